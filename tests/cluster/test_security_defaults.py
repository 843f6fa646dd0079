"""Secure by default: loopback binding, TLS helpers, safe YAML, nothing unpickled from a store."""

from __future__ import annotations

import argparse
import ast
import time
from pathlib import Path

import pytest

from mercury_dem.config import ConfigError, load_config
from mercury_dem.compute.security import (
    TlsFiles,
    add_tls_arguments,
    security_from_args,
    tls_environment,
    tls_security,
)
from tests.cluster.conftest import REPO, alive, listening_addresses, make_certs, refused


def _inc(x: int) -> int:
    return x + 1


@pytest.mark.integration  # starts a LocalCluster of worker processes
def test_default_local_cluster_binds_to_loopback() -> None:
    """connect() with the default configuration: scheduler, workers and dashboards on 127.0.0.1 only."""
    import psutil

    from mercury_dem.compute import ADJUST_RESOURCE, connect

    cfg = load_config()
    assert cfg.execution.host == "127.0.0.1"
    conn = connect(cfg.execution, scheduler="local", workers=2, threads_per_worker=1)
    try:
        client = conn.client
        assert client.scheduler.address.startswith("tcp://127.0.0.1:")
        assert client.dashboard_link.startswith("http://127.0.0.1:")
        workers = client.scheduler_info(n_workers=-1)["workers"]
        assert len(workers) == 2
        assert all(a.startswith("tcp://127.0.0.1:") for a in workers)
        assert all(w["resources"] == {ADJUST_RESOURCE: 1} for w in workers.values())
        assert client.submit(_inc, 1).result() == 2
        me = psutil.Process()
        procs = [me, *me.children(recursive=True)]
        socks = listening_addresses(procs)
        assert socks and {ip for _, ip, _ in socks} == {"127.0.0.1"}, socks
        # The worker processes (multiprocessing's resource tracker lives as long as this process).
        children = [p for p in procs[1:] if "resource_tracker" not in " ".join(p.cmdline())]
        assert len(children) >= 2
    finally:
        conn.close()
    deadline = time.monotonic() + 10
    while alive(children) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert alive(children) == []


@pytest.mark.integration  # starts a LocalCluster of worker processes
def test_local_cluster_over_tls_refuses_plain_tcp(tmp_path: Path) -> None:
    """connect(security=tls_security(...)) runs a TLS LocalCluster that a plain-TCP client cannot join."""
    from distributed import Client

    from mercury_dem.compute import connect

    files = TlsFiles.in_directory(make_certs(tmp_path / "tls"))
    conn = connect(load_config().execution, scheduler="local", workers=1, threads_per_worker=1,
                   security=tls_security(files))
    try:
        address = conn.client.scheduler.address
        assert address.startswith("tls://127.0.0.1:")
        assert conn.client.submit(_inc, 41).result() == 42
        refused(lambda: Client(address.replace("tls://", "tcp://"), timeout=10), "reset|closed")
    finally:
        conn.close()


def test_tls_files_are_checked_with_messages_naming_the_file(tmp_path: Path) -> None:
    files = TlsFiles.in_directory(make_certs(tmp_path / "tls"))
    assert files.check() is files
    with pytest.raises(ConfigError, match=r"key \(--tls-key\) .*nope\.pem"):
        TlsFiles(files.ca_file, files.cert, tmp_path / "nope.pem").check()
    (tmp_path / "junk.pem").write_text("not a certificate")
    with pytest.raises(ConfigError, match=r"junk\.pem is not a PEM file"):
        TlsFiles(tmp_path / "junk.pem", files.cert, files.key).check()
    # Key and certificate swapped: the certificate file holds no private key.
    with pytest.raises(ConfigError, match="private key"):
        TlsFiles(files.ca_file, files.cert, files.cert).check()
    env = tls_environment(files)
    assert env["DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION"] == "True"
    assert env["DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY"] == str(files.key.resolve())


def test_tls_cli_arguments_all_or_none(tmp_path: Path) -> None:
    files = TlsFiles.in_directory(make_certs(tmp_path / "tls"))
    p = argparse.ArgumentParser()
    add_tls_arguments(p)
    assert security_from_args(p.parse_args([])) is None
    sec = security_from_args(p.parse_args(["--tls-ca-file", str(files.ca_file), "--tls-cert", str(files.cert),
                                           "--tls-key", str(files.key)]))
    assert sec.require_encryption
    assert sec.tls_ca_file == str(files.ca_file.resolve())
    assert sec.tls_client_cert == sec.tls_scheduler_cert == sec.tls_worker_cert == str(files.cert.resolve())
    with pytest.raises(ConfigError, match="missing --tls-key"):
        security_from_args(p.parse_args(["--tls-ca-file", str(files.ca_file), "--tls-cert", str(files.cert)]))


def test_config_yaml_refuses_python_object_tags(tmp_path: Path) -> None:
    """A YAML tag that would construct a Python object is refused with ConfigError, and nothing is run."""
    marker = tmp_path / "pwned"
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "execution: !!python/object/apply:os.system\n"
        f"  - 'touch {marker}'\n"
    )
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)
    assert not marker.exists()
    obj = tmp_path / "obj.yaml"
    obj.write_text("execution: !!python/object:argparse.Namespace {scheduler: sync}\n")
    with pytest.raises(ConfigError, match="bad.yaml|obj.yaml"):
        load_config(obj)


# --- nothing from a run store is unpickled ---------------------------------------------------------

#: Modules whose loading of pickles is reviewed and allowed, with the reason ({"path": "why"}).
#: Empty: the package never unpickles. (Dask pickles tasks between our own processes; that is
#: transport inside one cluster, not reading a store, and lives in dask, not here.)
PICKLE_ALLOW_LIST: dict[str, str] = {}

_PICKLE_MODULES = {"pickle", "cPickle", "_pickle", "cloudpickle", "dill", "joblib", "shelve", "marshal", "jsonpickle"}


def _unsafe_loads(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, what) of every construct that can run code when it reads data."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, f"import {a.name}") for a in node.names if a.name.split(".")[0] in _PICKLE_MODULES]
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in _PICKLE_MODULES:
            found.append((node.lineno, f"from {node.module} import ..."))
        elif isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            base = f.value.id if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) else ""
            kw = {k.arg: k.value for k in node.keywords}
            if name in ("read_pickle", "unsafe_load", "full_load", "Unpickler") or (
                name in ("load", "loads") and base in _PICKLE_MODULES
            ):
                found.append((node.lineno, ast.unparse(f)))
            elif name == "load" and base == "yaml":
                loader = ast.unparse(kw["Loader"]) if "Loader" in kw else (
                    ast.unparse(node.args[1]) if len(node.args) > 1 else "")
                if not loader.endswith(("SafeLoader", "CSafeLoader")):
                    found.append((node.lineno, f"yaml.load(Loader={loader or 'default'})"))
            elif "allow_pickle" in kw and not (
                isinstance(kw["allow_pickle"], ast.Constant) and kw["allow_pickle"].value is False
            ):
                found.append((node.lineno, f"{ast.unparse(f)}(allow_pickle={ast.unparse(kw['allow_pickle'])})"))
            elif name in ("Pickle", "PickleCodec") or (name in ("eval", "exec") and isinstance(f, ast.Name)):
                found.append((node.lineno, ast.unparse(f)))
    return found


def test_the_scanner_finds_what_it_looks_for() -> None:
    src = (
        "import pickle\nimport numpy as np, pandas as pd, yaml\n"
        "a = pickle.loads(b)\nb = np.load(p, allow_pickle=True)\nc = pd.read_pickle(p)\n"
        "d = yaml.load(t, Loader=yaml.Loader)\ne = yaml.load(t, Loader=yaml.SafeLoader)\n"
        "f = np.load(p, allow_pickle=False)\ng = np.load(p)\n"
    )
    lines = sorted(line for line, _ in _unsafe_loads(ast.parse(src)))
    assert lines == [1, 3, 4, 5, 6]


def test_package_never_unpickles() -> None:
    pkg = REPO / "mercury_dem"
    offences = []
    for path in sorted(pkg.rglob("*.py")):
        rel = str(path.relative_to(REPO))
        if rel in PICKLE_ALLOW_LIST:
            continue
        try:
            tree = ast.parse(path.read_text(), filename=rel)
        except SyntaxError as exc:  # cannot vouch for a file this Python cannot parse
            offences.append(f"{rel}:{exc.lineno}: does not parse on this Python ({exc.msg}); fix it first")
            continue
        for line, what in _unsafe_loads(tree):
            offences.append(f"{rel}:{line}: {what}")
    assert not offences, "code that can execute data read from a store:\n" + "\n".join(offences)
