"""dpos-campaign's local Dask cluster: TLS with a temporary certificate, so that
another local process can neither run code in a worker nor talk to the scheduler, and no HTTP
route (no dashboard, no /metrics) on the scheduler or the workers.  The TLS part needs the
``cryptography`` package (Dask's ``Security.temporary()``); without it the cluster runs on plain
TCP with a warning, which the second test keeps."""

from __future__ import annotations

import urllib.error
import urllib.request

import pytest

from dpos_ros.cli import campaign

pytest.importorskip("distributed")

PATHS = ("/metrics", "/health", "/status", "/info/main/workers.html", "/json/identity.json")


def _http_status(port: int, path: str) -> int:
    try:
        return urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5).status
    except urllib.error.HTTPError as e:
        return e.code


@pytest.mark.slow
def test_local_cluster_is_tls_only_and_serves_no_http_route() -> None:
    pytest.importorskip("cryptography")
    import distributed

    with campaign.dask_engine(None, 1, 20.0) as eng:
        addr = eng.info["scheduler"]
        assert eng.info["tls"] is True and addr.startswith("tls://127.0.0.1:"), eng.info
        assert eng.client.submit(abs, -2).result(timeout=60) == 2  # the run's own client works (a builtin: picklable by name)
        info = eng.client.scheduler_info(n_workers=-1)
        ports = [info["services"]["dashboard"]] + [w["services"]["dashboard"] for w in info["workers"].values()]
        for port in ports:  # Dask's HTTP server listens, on 127.0.0.1, with no route
            assert {path: _http_status(port, path) for path in PATHS} == dict.fromkeys(PATHS, 404)
        for other in (addr.replace("tls://", "tcp://"), addr):  # plain TCP; TLS without the run's certificate
            with pytest.raises(Exception):  # noqa: B017 - Dask raises several kinds (CommClosedError, TypeError, OSError)
                c = distributed.Client(other, timeout=3, set_as_default=False)
                c.close()


def test_without_cryptography_the_cluster_says_it_runs_without_tls(monkeypatch, capsys) -> None:
    import distributed

    def no_cryptography(cls, **kwargs):
        raise ImportError("Using `Security.temporary` requires `cryptography`")

    monkeypatch.setattr(distributed.security.Security, "temporary", classmethod(no_cryptography))
    assert campaign.local_security(distributed) is None
    err = capsys.readouterr().err
    assert "without TLS" in err and "cryptography" in err and len(err.strip().splitlines()) == 1
