"""dpos-campaign: recordings and Monte Carlo runs on a Dask LocalCluster of 2 workers (no ROS/DDS;
the cluster listens on dynamic ports of 127.0.0.1, so it runs beside other tests)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from dpos_core.config import config_text
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.cli import campaign, evaluate
from dpos_ros.cli import campaign_tasks as ct
from dpos_ros.cli import process as process_cli
from dpos_ros.devices.sim_streams import session_custom_data, session_streams
from dpos_ros.io import bag

EXE = Path(sys.executable).parent


def _sim_bag(path: Path, seed: int, duration_s: float = 20.0) -> Path:
    """A short recording of paper_su with both wings' sub-IMUs (paper_su_pair), truth included."""
    sc = load_scenario("paper_su", aircraft="paper_su_pair")
    ss = SimulatedSession(sc, seed, duration_s)
    bag.write_streams(path, session_streams(ss), custom_data=session_custom_data(ss, config_text("aircraft", "paper_su_pair")))
    return path


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    d = tmp_path_factory.mktemp("campaign_recs")
    broken = d / "rec_broken"
    broken.mkdir()  # an empty directory: neither a rosbag2 nor a spill
    return [_sim_bag(d / "rec_a", 1), broken, _sim_bag(d / "rec_b", 2)]


def _close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)


def _same_numbers(x, y, path: str = "") -> list[str]:
    """Where two JSON trees differ (numbers with a tolerance; ``timing`` left out: wall clock)."""
    if isinstance(x, dict) and isinstance(y, dict):
        if set(x) != set(y):
            return [f"{path}: keys {sorted(x)} != {sorted(y)}"]
        return [d for k in x if k != "timing" for d in _same_numbers(x[k], y[k], f"{path}.{k}")]
    if isinstance(x, list) and isinstance(y, list):
        if len(x) != len(y):
            return [f"{path}: {len(x)} != {len(y)} items"]
        return [d for i, (a, b) in enumerate(zip(x, y, strict=True)) for d in _same_numbers(a, b, f"{path}[{i}]")]
    if isinstance(x, float | int) and isinstance(y, float | int) and not isinstance(x, bool):
        return [] if _close(float(x), float(y)) else [f"{path}: {x} != {y}"]
    return [] if x == y else [f"{path}: {x!r} != {y!r}"]


@pytest.mark.slow
def test_process_campaign_on_a_local_cluster(recordings: list[Path], tmp_path: Path) -> None:
    """Three recordings, one broken, on a LocalCluster of 2 workers: the broken one is retried
    once and reported failed with dpos-process's error, the others give exactly dpos-process's
    products; one line per recording, campaign.json lists all three."""
    out = tmp_path / "out"
    r = subprocess.run([str(EXE / "dpos-campaign"), "process", *map(str, recordings), "--out", str(out), "--workers", "2",
                        "--method", "urtss"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stdout + r.stderr  # one recording failed
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("[")]
    assert sorted(ln[:5] for ln in lines) == ["[1/3]", "[2/3]", "[3/3]"]
    assert any("failed  rec_broken" in ln and "not a rosbag2 directory" in ln for ln in lines), r.stdout
    assert "local Dask cluster" in r.stdout and "2 worker(s)" in r.stdout
    assert "3 recording(s): 2 ok, 0 partial, 1 failed" in r.stdout
    assert "%|" not in r.stderr and "\r" not in r.stderr  # no progress bar: stderr is not a terminal

    s = json.loads((out / "campaign.json").read_text())
    assert (s["kind"], s["tasks"], s["ok"], s["partial"], s["failed"]) == ("process", 3, 2, 0, 1)
    assert s["options"] == ["--method", "urtss"]
    recs = {x["name"]: x for x in s["records"]}
    assert [x["name"] for x in s["records"]] == ["rec_a", "rec_broken", "rec_b"]  # the order given
    bad = recs["rec_broken"]
    assert bad["status"] == "failed" and bad["exit_status"] == 2 and bad["attempt"] == 2  # 1 retry (the default)
    assert str(recordings[1]) in bad["error"] and "not a rosbag2 directory" in bad["error"]
    # the workers: one BLAS thread each, the dpos kernels' numba cache usable
    assert s["engine"]["cluster"] == "local" and s["engine"]["workers"] == 2
    for info in s["engine"]["worker_info"].values():
        assert set(info["threads_env"].values()) == {"1"}
    numba = s["engine"]["numba"].values()
    assert all(st["numba"] and st["cache_writable"] for st in numba)
    assert sum(st["loaded_from_cache"] + st["compiled"] for st in numba) > 0  # (a worker may have had only the broken one)

    for name, seed in (("rec_a", 1), ("rec_b", 2)):
        rec = recs[name]
        assert rec["status"] == "ok" and rec["exit_status"] == 0 and rec["attempt"] == 1
        products = out / name / f"paper_su_seed{seed}"
        assert Path(rec["products"]) == products and (products / "ant_l.csv").is_file()
        assert json.loads((out / name / "task.json").read_text()) == rec  # the worker's record, on disk
        status = json.loads((products / "status.json").read_text())
        f = rec["figures"]
        assert f["session_id"] == status["session_id"] and (f["estimated"], f["antennas"]) == (2, 2)
        assert f["qc_verdicts"] == {n: q["verdict"] for n, q in status["qc"]["antennas"].items()}
        assert f["rmse"] == json.loads((products / "metrics.json").read_text())["methods"]["urtss"]["mean"]["rmse"]
        assert "products in" in (out / name / "process.log").read_text()

    # exactly what dpos-process gives on its own
    assert process_cli.main([str(recordings[0]), "--method", "urtss", "--workers", "1", "--out", str(tmp_path / "alone")]) == 0
    alone = json.loads((tmp_path / "alone" / "paper_su_seed1" / "metrics.json").read_text())
    assert not _same_numbers(json.loads((out / "rec_a" / "paper_su_seed1" / "metrics.json").read_text()), alone)


@pytest.mark.slow
def test_eval_campaign_equals_dpos_eval(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """3 runs of 20 s of paper_su in 2 tasks (runs per task 2) on 2 workers: metrics.json and
    report.md equal dpos-eval's with the same seeds (the timing aside)."""
    common = ["--scenario", "paper_su", "--methods", "urtss,ups", "--particles", "20", "--duration", "20", "--runs", "3", "--seed", "4"]
    r = subprocess.run([str(EXE / "dpos-campaign"), "eval", *common, "--runs-per-task", "2", "--workers", "2",
                        "--out", str(tmp_path / "campaign")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert evaluate.main([*common, "--out", str(tmp_path / "eval")]) == 0
    capsys.readouterr()
    c = json.loads((tmp_path / "campaign" / "metrics.json").read_text())
    e = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert c["runs"] == 3 and not _same_numbers(c, e)

    def no_timing(p: Path) -> list[str]:
        return [ln for ln in p.read_text().splitlines() if "processing" not in ln]

    assert no_timing(tmp_path / "campaign" / "report.md") == no_timing(tmp_path / "eval" / "report.md")
    s = json.loads((tmp_path / "campaign" / "campaign.json").read_text())
    assert [x["seeds"] for x in s["records"]] == [[4, 5], [6]] and s["combined_runs"] == 3 and s["failed_seeds"] == []
    assert "[2/2] ok" in r.stdout and "run 3/3 seed 6  urtss" in r.stdout


@pytest.mark.slow
def test_engine_retries_and_reports(tmp_path: Path) -> None:
    """A task that fails once succeeds on its retry; one that keeps failing is reported (not
    raised) while the others finish."""
    # (local functions: pickled by value, the workers cannot import this test module)
    def flaky(marker: Path) -> str:
        """Fails on its first call (no marker yet), succeeds on the next."""
        if not marker.exists():
            marker.touch()
            raise RuntimeError("first attempt fails")
        return "second attempt"

    def always_fails(x: int) -> int:
        raise ValueError(f"task {x} cannot succeed")

    done: list[int] = []
    with campaign.dask_engine(None, 2, 20.0) as engine:
        assert engine.info["workers"] == 2 and engine.info["scheduler"].startswith("tls://127.0.0.1:")
        res = campaign.run_tasks(engine, flaky, [tmp_path / "m"], ["flaky"], 1, lambda i, r, e: done.append(i))
        assert res[0] == ("second attempt", None)
        res = campaign.run_tasks(engine, flaky, [tmp_path / "m2"], ["flaky0"], 0, lambda i, r, e: done.append(i))
        assert res[0][0] is None and "first attempt fails" in str(res[0][1])  # no retry
        res = campaign.run_tasks(engine, always_fails, [1, 2], ["bad", "bad2"], 2, lambda i, r, e: done.append(i))
        assert all(isinstance(e, ValueError) for _, e in res) and "task 2 cannot succeed" in str(res[1][1])
    assert sorted(done) == [0, 0, 0, 1]


def test_task_list_and_records(recordings: list[Path], tmp_path: Path) -> None:
    """The engine-independent part: the task list's checks, a failing task's record and its
    attempt count (a retry in the same campaign counts on), the summary and the lines."""
    tasks = ct.process_tasks(recordings, tmp_path / "o", ["--method", "urtss"], "c1")
    assert [t.name for t in tasks] == ["rec_a", "rec_broken", "rec_b"] and tasks[0].out == (tmp_path / "o" / "rec_a").resolve()
    with pytest.raises(ct.CampaignError, match="not found: .*nope"):
        ct.process_tasks([recordings[0], tmp_path / "nope"], tmp_path / "o", [], "c1")
    twin = tmp_path / "twin" / "rec_a"
    twin.mkdir(parents=True)
    with pytest.raises(ct.CampaignError, match="same name"):
        ct.process_tasks([recordings[0], twin], tmp_path / "o", [], "c1")

    broken = tasks[1]
    for attempt in (1, 2):
        with pytest.raises(ct.TaskFailed, match="not a rosbag2 directory") as ei:
            ct.run_process_task(broken)
        assert ei.value.attempt == attempt
    with pytest.raises(ct.TaskFailed) as ei:  # another campaign starts at 1
        ct.run_process_task(ct.ProcessTask(broken.name, broken.recording, broken.out, broken.options, "c2"))
    assert ei.value.attempt == 1
    rec = ct.failed_record(ct.ProcessTask(broken.name, broken.recording, broken.out, broken.options, "c2"), ei.value, retries=1)
    assert rec["status"] == "failed" and rec["exit_status"] == 2 and "not a rosbag2 directory" in rec["error"]
    assert "failed  rec_broken" in ct.result_line(2, 3, rec)
    other = ct.failed_record(tasks[0], RuntimeError("worker died"), retries=2)
    assert other["attempt"] == 3 and other["error"] == "RuntimeError: worker died"
    s = ct.summary("process", [rec, other, {"name": "x", "status": "ok"}], engine={}, wall_s=1.0)
    assert (s["ok"], s["partial"], s["failed"], s["tasks"]) == (1, 0, 2, 3)
    batches = ct.eval_tasks(evaluate.TAPlan(load_scenario("paper_su"), ("urtss",), 1, 5.0, 0.0, None, True), 5, 10, 2)
    assert [b.seeds for b in batches] == [(10, 11), (12, 13), (14,)] and [b.first_run for b in batches] == [0, 2, 4]


def test_bad_input_is_exit_2(recordings: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A missing recording, an unreachable scheduler, bad options: exit 2, naming what is wrong."""
    assert campaign.main(["process", str(recordings[0]), str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    assert "recording(s) not found" in capsys.readouterr().err
    assert campaign.main(["process", str(recordings[0]), "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:9",
                          "--connect-timeout", "0.5"]) == 2
    assert "cannot connect to the Dask scheduler at tcp://127.0.0.1:9" in capsys.readouterr().err
    for argv, text in ((["--scheduler", "nohost:x"], "not a scheduler address"), (["--retries", "-1"], "--retries must be >= 0"),
                       (["--particles", "0"], "--particles must be >= 1"), (["--method", "nope"], "invalid choice")):
        with pytest.raises(SystemExit) as ei:
            campaign.main(["process", str(recordings[0]), "--out", str(tmp_path / "o"), *argv])
        assert ei.value.code == 2 and text in capsys.readouterr().err
    with pytest.raises(SystemExit):
        campaign.main(["eval", "--scenario", "paper_ifa", "--out", str(tmp_path / "e")])
    assert "in-flight alignment" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_dpos_process_options_are_passed_on(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The options that differ from dpos-process's defaults, an aircraft file made absolute."""
    monkeypatch.chdir(tmp_path)
    Path("my_aircraft.yaml").write_text(config_text("aircraft", "paper_su_pair"))
    Path("egm.pgm").write_bytes(b"P5\n")
    ap, subs, forwarded = campaign._parsers()
    args = ap.parse_args(["process", "r1", "r2", "--out", "o", "--method", "ukf", "--no-sigma-inflation", "--particles", "100",
                          "--aircraft", "my_aircraft.yaml", "--workers", "3", "--quiet", "--geoid", "egm.pgm"])
    assert args.recordings == [Path("r1"), Path("r2")] and args.workers == 3 and args.quiet  # (the campaign's own, not passed on)
    assert campaign.forwarded_argv(args, forwarded) == ["--method", "ukf", "--no-sigma-inflation", "--aircraft",
                                                        str(tmp_path.resolve() / "my_aircraft.yaml"), "--geoid", str(tmp_path.resolve() / "egm.pgm")]
