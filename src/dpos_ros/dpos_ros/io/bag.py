"""rosbag2 (MCAP) writing and reading (no ROS installation needed).

Bags are written with zstd chunk compression (rosbags ``CompressionMode.STORAGE``), messages in
stamp order, log time = ``header.stamp``.  Reading returns raw CDR per topic so the vectorized
decoder of :mod:`dpos_ros.contract.cdr` (or ``rclpy.serialization``) can be used.

Both go through the chunk-at-a-time fast path of :mod:`dpos_ros.io._mcap` (no Python object per
message; the file laid out as rosbags' writer lays it out, the messages read in the order of its
reader); a bag that path does not read (another storage, an MCAP without summary or chunk index)
is read by rosbags' ``AnyReader``.
"""

from __future__ import annotations

import copy
import functools
import warnings
from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from importlib.metadata import version
from pathlib import Path

import numpy as np
import yaml
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from dpos_ros.contract.topics import QOS_KINDS, qos_kind
from dpos_ros.io import _mcap, _mcap_recover
from dpos_ros.io.messages import Messages, RawTopic
from dpos_ros.io.streams import TopicStream, merged_order

ROSBAG2_VERSION = 9
#: the MCAP header's ``library``: the writer, truthfully (the rosbag2 layout follows rosbags' writer)
LIBRARY = f"dpos_ros-{version('dpos_ros')}"
#: a batch laid out and compressed for a writer (:func:`encode_streams`)
EncodedBatch = _mcap.EncodedBatch


def typestore():
    return get_typestore(Stores.ROS2_JAZZY)


def write_streams(
    path: Path,
    streams: list[TopicStream],
    progress: Callable[[int, int], None] | None = None,
    custom_data: dict[str, str] | None = None,
) -> int:
    """Write the streams to a new rosbag2 directory ``path``; returns the message count.

    ``custom_data`` goes into the rosbag2 metadata (``dpos.*`` keys describe the session)."""
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists: choose a new output directory (rosbag2 writes a new one)")

    n = _mcap.write(path, _topics(streams), merged_order(streams) if streams else (np.zeros(0, dtype=np.int64),) * 3,
                    dict(custom_data or {}), ROSBAG2_VERSION, LIBRARY, progress, [design_qos(s.topic) for s in streams])
    if progress is not None:
        progress(n, n)
    return n


def design_qos(topic: str) -> list[Qos]:
    """The QoS profile dpos publishers of ``topic`` offer (docs/design.md, QoS; the numbers of
    :data:`dpos_ros.contract.topics.QOS_KINDS`), as rosbag2's ``offered_qos_profiles`` entry: the
    datum and the statuses TRANSIENT_LOCAL, so that a replay with ``ros2 bag play`` latches them."""
    history, depth, reliability, durability = QOS_KINDS[qos_kind(topic)]
    zero = QosTime(0, 0)  # rclpy's defaults (deadline, lifespan, lease: none), as dpos-record stores them
    return [Qos(history=QosHistory[history.upper()], depth=depth, reliability=QosReliability[reliability.upper()],
                durability=QosDurability[durability.upper()], deadline=zero, lifespan=zero,
                liveliness=QosLiveliness.SYSTEM_DEFAULT, liveliness_lease_duration=zero, avoid_ros_namespace_conventions=False)]


def _topics(streams: Sequence[TopicStream]) -> list[_mcap.Topic]:
    return [_mcap.Topic(s.topic, s.msgtype, s.t_ns, Messages.from_rows(s.rows) if s.rows is not None
                        else Messages.from_list(s.blobs or ())) for s in streams]


def new_writer(path: Path, channels: Sequence[tuple[str, str]], custom_data: dict[str, str] | None = None) -> _mcap.Writer:
    """A rosbag2 directory ``path`` (new) written batch by batch (``channels``: (topic, type) in
    the order of every batch's streams): :meth:`~dpos_ros.io._mcap.Writer.add` or, for batches encoded
    on other processes (:func:`encode_streams`), :meth:`~dpos_ros.io._mcap.Writer.add_encoded`;
    :meth:`~dpos_ros.io._mcap.Writer.close` at the end, :func:`abort_writer` on failure."""
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists: choose a new output directory (rosbag2 writes a new one)")

    return _mcap.Writer(path, list(channels), dict(custom_data or {}), ROSBAG2_VERSION, LIBRARY,
                        qos=[design_qos(topic) for topic, _ in channels])


def abort_writer(w: _mcap.Writer) -> None:
    """Stop a failed :func:`new_writer` (its compression threads, its file; the caller removes the directory)."""
    w.pool.shutdown(wait=True, cancel_futures=True)
    w.f.close()


def encode_streams(streams: Sequence[TopicStream], prefix: bytes = b"") -> EncodedBatch:
    """One batch of streams (the writer's channels, in order) laid out and compressed as
    :meth:`~dpos_ros.io._mcap.Writer.add` would (a process pool's task); ``prefix``: the writer's
    ``prefix`` for the file's first batch."""
    return _mcap.encode_batch(_topics(streams), merged_order(list(streams)), prefix)


def write_stream_batches(
    path: Path,
    batches: Iterable[list[TopicStream]],
    progress: Callable[[int], None] | None = None,
    custom_data: dict[str, str] | None = None,
) -> tuple[int, list[tuple[str, str, int]]]:
    """Write batches of streams (each the same topics in the same order, e.g.
    :func:`dpos_ros.devices.sim_streams.chunked_session_streams`) to a new rosbag2 directory, one
    batch in memory at a time; returns the message count and ``(topic, type, count)`` per topic.
    ``progress(t_ns)`` after each batch with its last stamp."""
    if Path(path).exists():  # (before the first batch is made)
        raise FileExistsError(f"{path} exists: choose a new output directory (rosbag2 writes a new one)")
    w: _mcap.Writer | None = None
    try:
        for streams in batches:
            if w is None:
                w = new_writer(Path(path), [(s.topic, s.msgtype) for s in streams], custom_data)
            w.add(_topics(streams), merged_order(streams))
            if progress is not None:
                progress(max((int(s.t_ns[-1]) for s in streams if len(s)), default=0))
        if w is None:
            raise ValueError("no batch of streams to write")
        w.close()
    except BaseException:
        if w is not None:
            abort_writer(w)
        raise
    return w.n, [(t, m, int(c)) for (t, m), c in zip(w.channels, w.counts, strict=True)]


def write_streams_rosbags(
    path: Path,
    streams: list[TopicStream],
    custom_data: dict[str, str] | None = None,
) -> int:
    """:func:`write_streams` through rosbags' ``Writer``, message by message (the reference the
    fast path is tested against: the same offered QoS profiles; the MCAP header's library and the
    metadata's ``ros_distro`` are rosbags' own)."""
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists: choose a new output directory (rosbag2 writes a new one)")
    ts = typestore()
    t, si, mi = merged_order(streams)
    n = len(t)
    w = Writer(path, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP)
    w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    for key, value in (custom_data or {}).items():
        w.set_custom_data(key, value)
    w.open()
    try:
        conns = [w.add_connection(s.topic, s.msgtype, typestore=ts, offered_qos_profiles=design_qos(s.topic)) for s in streams]
        for k in range(n):
            s = streams[si[k]]
            w.write(conns[si[k]], int(t[k]), s.message(int(mi[k])))
    finally:
        w.close()
    return n


#: custom_data key of a recovery (:func:`readable_bag`): the messages lost in the chunks it skipped
RECOVERY_LOST_KEY = "dpos.recovery_lost_messages"
#: suffix of the directory a bag without metadata is recovered into (:func:`readable_bag`)
RECOVERED_SUFFIX = ".recovered"


def readable_bag(path: Path, verify: bool = False) -> tuple[Path, str | None]:
    """The bag to read for ``path``, and what was done to make it readable (None: nothing).

    A recorder killed before it closed its bag (SIGKILL, power loss, a full disk) leaves a
    directory with an MCAP file but no ``metadata.yaml``, and an MCAP without its summary; rosbags
    reads neither. A bag whose MCAP has no footer (cut short, with or without its metadata.yaml),
    or whose summary or chunk index points past the end of its data (:func:`dpos_ros.io._mcap.damage`),
    is no better. Such a bag is recovered into the new directory ``<path>.recovered``: the MCAP is
    read record by record from its start (:func:`dpos_ros.io._mcap_recover.scan`: bad chunks skipped and
    said, allocations bounded by the file), and every complete message is written with its channel
    and log time into a rosbag2 there; the original is not touched. ``verify``: also decompress
    every chunk and check its CRC (for readers that do not check them, e.g. rosbags' behind
    dpos-play): a bad chunk makes a recovery too. A recovered directory that exists already is
    reused. Raises :class:`ValueError` naming the path when there is nothing to recover (no .mcap,
    several, or no complete message).
    """
    path = Path(path)
    if path.is_file() and path.suffix == ".mcap":
        path = path.parent
    if path.name in ("", ".."):  # "." or "..": its recovery <name>.recovered needs a real name
        path = path.resolve()
    if not path.is_dir():
        return path, None
    why: str | None = None
    if (path / "metadata.yaml").is_file():
        file = _single_mcap(path)
        if file is None:
            return path, None
        why = _mcap.damage(file)
        if why is None and verify:
            bad: list[str] = []
            _verify(file, bad)
            why = f"{len(bad)} bad chunk(s)" if bad else None
        if why is None:
            return path, None
        files = [file]
    else:
        files = sorted(path.glob("*.mcap"))
        if len(files) != 1:
            return path, None  # not ours to guess: the reader says what is missing
    out = path.with_name(path.name + RECOVERED_SUFFIX)
    if (out / "metadata.yaml").is_file():
        return out, f"{path} {'has no metadata.yaml' if why is None else f'is damaged ({why})'}: reading its recovery {out} (made earlier)"
    n, topics, stop = _recover_mcap(files[0], out, custom_data(path))
    what = "has no metadata.yaml (a recording that was not closed)" if why is None else f"is damaged: {files[0].name}: {why}"
    return out, f"{path} {what}: recovered {n} messages on {topics} topics from {files[0].name} into {out}; {stop}"


def _verify(file: Path, bad: list[str]) -> None:
    """Append to ``bad`` a warning per chunk of ``file`` that cannot be read (every chunk decompressed, its CRC checked)."""
    _mcap.read(file, None, bad)


def _recover_mcap(src: Path, out: Path, custom: dict[str, str] | None = None) -> tuple[int, int, str]:
    """Copy the complete messages of the MCAP ``src`` into a new rosbag2 ``out`` (:func:`readable_bag`):
    (messages, topics, what was lost and where the reading stopped)."""
    ts = typestore()
    got = _mcap_recover.scan(src)
    stop = "; ".join(got.notes)
    if got.lost:
        stop = f"{got.lost} message(s) lost in skipped chunks; {stop}"
    channels, schemas = got.channels, got.schemas
    msgs = [m for m in got.messages if m[0] in channels and channels[m[0]][1] in schemas]
    if not msgs:
        raise ValueError(f"{src}: no complete message in the MCAP ({stop})")
    for _, sid in channels.values():
        name, enc, data = schemas.get(sid, ("", "", b""))
        if name and name not in ts.fielddefs and enc == "ros2msg":
            ts.register(get_types_from_msg(data.decode(), name))
    w = Writer(out, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP)
    w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    for key, value in (custom or {}).items():  # (the metadata.yaml of a damaged bag that has one)
        w.set_custom_data(key, value)
    w.set_custom_data("dpos.recovered_from", str(src))
    if got.lost:
        w.set_custom_data(RECOVERY_LOST_KEY, str(got.lost))
    w.open()
    try:
        conns = {cid: w.add_connection(topic, schemas[sid][0], typestore=ts)
                 for cid, (topic, sid) in channels.items() if sid in schemas}
        for cid, t, data in sorted(msgs, key=lambda m: m[1]):
            if cid in conns:
                w.write(conns[cid], t, data)
    finally:
        w.close()
    return len(msgs), len({channels[c][0] for c, _, _ in msgs}), stop


def read_raw(path: Path, topics: Iterable[str] | Callable[[str], bool] | None = None,
             notes: list[str] | None = None) -> dict[str, RawTopic]:
    """Every message of a bag as ``{topic: (msgtype, log times [ns], raw CDR)}`` (:class:`RawTopic`,
    the messages a :class:`Messages`), in log-time order (ties in file order).  A bag without
    metadata is recovered first (:func:`readable_bag`); what was recovered is appended to
    ``notes`` (or warned about when it is None), and so is each corrupt chunk, skipped (naming
    the file, the chunk, its log time range and the messages lost); rosbags' own errors for what
    the fast path leaves to it."""
    path, note = readable_bag(Path(path))
    if note is not None:
        if notes is None:
            warnings.warn(note, stacklevel=2)
        else:
            notes.append(note)

    wanted: Callable[[str], bool] | None = None
    if callable(topics):
        wanted = topics
    elif topics is not None:
        wanted = set(topics).__contains__
    file = _single_mcap(path)
    if file is not None:
        bad = notes if isinstance(notes, _mcap.Notes) else _mcap.Notes()
        fast = _mcap.read(file, wanted, bad)  # a bad chunk is skipped and said (once in a Notes, and counted)
        if bad is not notes and bad:
            if notes is None:
                for w in bad:
                    warnings.warn(w, stacklevel=2)
            else:
                notes.extend(bad)
        if fast is not None:
            return fast
    return read_raw_rosbags(path, wanted)


#: the YAML loader of the bags' metadata: libyaml's when PyYAML was built with it (~10x faster)
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def bag_info(path: Path) -> dict:
    """The ``rosbag2_bagfile_information`` mapping of the rosbag2 directory ``path``'s
    ``metadata.yaml`` ({} when the file holds none; a copy the caller may change).

    Raises OSError when the file cannot be read and ``yaml.YAMLError`` when it is not YAML. A
    session's metadata is read once per change of the file (its size and modification time), not
    once per reader: a recording's metadata lists every topic and its QoS (26 kB for a 10 s wing
    session) and one ``dpos-process`` run asks for it dozens of times."""
    meta = Path(path) / "metadata.yaml"
    st = meta.stat()
    return copy.deepcopy(_parsed_info(str(meta.resolve()), st.st_mtime_ns, st.st_size))


@functools.lru_cache(maxsize=32)
def _parsed_info(meta: str, mtime_ns: int, size: int) -> dict:
    """:func:`bag_info` of the file ``meta`` as it was at ``mtime_ns`` / ``size`` (the cache's key)."""
    doc = yaml.load(Path(meta).read_text(), Loader=_YAML_LOADER)  # noqa: S506 (a safe loader)
    info = doc.get("rosbag2_bagfile_information", {}) if isinstance(doc, dict) else {}
    return info if isinstance(info, dict) else {}


def _single_mcap(path: Path) -> Path | None:
    """The one MCAP file of a rosbag2 directory (``metadata.yaml`` with storage ``mcap`` and one
    file), else None."""
    meta = path / "metadata.yaml"
    if not meta.is_file():
        return None
    try:
        info = bag_info(path)
    except yaml.YAMLError:
        return None  # rosbags says what is wrong with it
    files = info.get("relative_file_paths") or []
    if info.get("storage_identifier") != "mcap" or len(files) != 1 or not str(files[0]).endswith(".mcap"):
        return None
    file = path / str(files[0])
    return file if file.is_file() else None


def read_raw_rosbags(path: Path, wanted: Callable[[str], bool] | None = None) -> dict[str, RawTopic]:
    """:func:`read_raw` of a readable bag through rosbags' ``AnyReader``, message by message (any
    storage rosbags reads; the reference the fast path is tested against)."""
    times: dict[str, list[int]] = defaultdict(list)
    data: dict[str, list[bytes]] = defaultdict(list)
    types: dict[str, str] = {}
    with AnyReader([Path(path)], default_typestore=typestore()) as r:
        conns = [c for c in r.connections if wanted is None or wanted(c.topic)]
        for c in conns:
            types[c.topic] = c.msgtype
        for c, t, raw in r.messages(connections=conns):
            times[c.topic].append(t)
            data[c.topic].append(bytes(raw))
    return {topic: RawTopic(mt, times[topic], Messages.from_list(data[topic])) for topic, mt in types.items()}


def rows(blobs: Sequence[bytes]) -> np.ndarray:
    """Fixed-size CDR messages as an (N, size) uint8 array (for :func:`dpos_ros.contract.cdr.decode`)."""
    if not len(blobs):
        return np.zeros((0, 0), dtype=np.uint8)
    return Messages.from_list(blobs).rows()


def custom_data(path: Path) -> dict[str, str]:
    """The rosbag2 metadata's ``custom_data`` (empty for bags without it)."""
    if not (Path(path) / "metadata.yaml").is_file():
        return {}
    return {str(k): str(v) for k, v in (bag_info(path).get("custom_data") or {}).items()}


def topics_and_duration(path: Path) -> tuple[list[str], float] | None:
    """The topics and the duration [s] the rosbag2 metadata lists, or None without readable metadata."""
    meta = Path(path) / "metadata.yaml"
    if not meta.is_file():
        return None
    try:
        info = bag_info(path)
        topics = [str(t["topic_metadata"]["name"]) for t in info.get("topics_with_message_count") or []]
        return topics, float((info.get("duration") or {}).get("nanoseconds", 0)) * 1e-9
    except (yaml.YAMLError, KeyError, TypeError, ValueError):
        return None
