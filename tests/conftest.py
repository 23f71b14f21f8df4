"""Shared fixtures: configs composed into tmp_path, a synthetic dataset written once per session,
and the location of the real archives (MOTION_ARCHIVES)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from omegaconf import DictConfig

from src.cli import register_resolvers
from src.data.normalization import Normalizer
from src.prepare import compose_config  # noqa: F401  (re-exported for the tests)

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
register_resolvers()


def identity_normalizer(num_features: int) -> Normalizer:
    """Identity statistics of the right shape (a state_dict loaded into it replaces them)."""
    ones = torch.ones(num_features)
    return Normalizer(torch.zeros(num_features), ones, ones.bool())


@pytest.fixture(scope="session")
def archives() -> Path:
    """Folder with the real h3.6m.zip / cmu_mocap.zip, or skip."""
    value = os.environ.get("MOTION_ARCHIVES")
    if not value:
        pytest.skip("real data not provided: set MOTION_ARCHIVES to the folder with the archives")
    path = Path(value)
    if not path.is_dir():
        pytest.skip(f"MOTION_ARCHIVES={value} is not a folder")
    return path


@pytest.fixture(scope="session")
def synthetic_data_dir(tmp_path_factory) -> Path:
    """A data_dir holding the synthetic H3.6M-format dataset, written once per session."""
    from src.data.synthetic import write_synthetic_h36m

    root = tmp_path_factory.mktemp("data")
    write_synthetic_h36m(root / "synthetic")
    return root


@pytest.fixture
def train_cfg(tmp_path, synthetic_data_dir):
    """A factory: train_cfg(*overrides) -> composed train config on synthetic data."""

    def make(*overrides: str) -> DictConfig:
        return compose_config(
            "train",
            ["data=synthetic", "trainer=cpu", "iterations=4", "val_every=2", *overrides],
            tmp_path / "run",
            synthetic_data_dir,
        )

    return make


def refused(message: str, *named: str) -> None:
    """A message test: the message names the offending key (or file) and the fix, in any words
    (issue 52: a reworded message breaks no test)."""
    assert all(part in message for part in named), (message, named)


def run_module(module: str, *args: str, data_dir: Path, log_dir: Path, timeout: int = 600):
    """Run `python -m <module> args...` as a user would; returns the CompletedProcess."""
    env = {**os.environ, "MOTION_DATA_DIR": str(data_dir), "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-m", module, f"paths.log_dir={log_dir}", *args]
    return subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)


CTRL_C_AT = """
import os, pkgutil, runpy, signal, sys, time
owner, name, after, module = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
# As in a terminal: a pytest-xdist worker ignores SIGINT, and its children inherit that.
signal.signal(signal.SIGINT, signal.default_int_handler)
target = pkgutil.resolve_name(owner)
original, calls = getattr(target, name), []
def ctrl_c(*args, **kwargs):
    calls.append(1)
    if len(calls) > after:
        os.kill(os.getpid(), signal.SIGINT)  # what a terminal sends on Ctrl-C
        time.sleep(60)  # the KeyboardInterrupt is raised here
    return original(*args, **kwargs)
setattr(target, name, ctrl_c)
sys.argv = [module, *sys.argv[5:]]
runpy.run_module(module, run_name="__main__", alter_sys=True)
"""


def run_interrupted(at: tuple[str, str], after: int, module: str, *args: str, data_dir, log_dir):
    """run_module with a Ctrl-C (a real SIGINT) at call `after` + 1 of attribute at[1] of at[0]
    (a module, or "module:Class" as pkgutil.resolve_name takes it): at a chosen point, no race."""
    env = {**os.environ, "MOTION_DATA_DIR": str(data_dir), "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-c", CTRL_C_AT, *at, str(after), module]
    cmd += [f"paths.log_dir={log_dir}", *args]
    return subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)


ONE_PROCESS = """
import contextlib, io, json, runpy, sys
from hydra.core.global_hydra import GlobalHydra
results = []
for argv in json.loads(sys.argv[1]):
    sys.argv, out, err, code = argv, io.StringIO(), io.StringIO(), 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            runpy.run_module(argv[0], run_name="__main__")
        except SystemExit as e:
            code = 0 if e.code is None else e.code
    GlobalHydra.instance().clear()
    results.append([code, out.getvalue(), err.getvalue()])
print(json.dumps(results))
"""


def run_in_one_process(*invocations: list[str], data_dir: Path, log_dir: Path | None):
    """`python -m <module> args...` for each [module, *args], one after the other in one
    process, as run_module would run them: importing torch and Lightning is most of a short
    run. Returns a CompletedProcess (returncode, stdout, stderr) per invocation. With
    log_dir=None each invocation gives its own paths.log_dir=."""
    log = [] if log_dir is None else [f"paths.log_dir={log_dir}"]
    argvs = [[m, *log, *args] for m, *args in invocations]
    env = {**os.environ, "MOTION_DATA_DIR": str(data_dir), "PYTHONUNBUFFERED": "1"}
    proc = subprocess.run(
        [sys.executable, "-c", ONE_PROCESS, json.dumps(argvs)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads(proc.stdout.splitlines()[-1])
    return [subprocess.CompletedProcess(a, *r) for a, r in zip(argvs, results, strict=True)]


@pytest.fixture(scope="session")
def help_text(tmp_path_factory):
    """help_text(module): what `python -m <module> --help` prints, for every entry point from
    one process."""
    modules = ["src.train", "src.eval", "src.visualize", "src.plot_errors", "src.report"]
    modules += ["src.export_windows"]
    tmp = tmp_path_factory.mktemp("help")
    procs = run_in_one_process(*([m, "--help"] for m in modules), data_dir=tmp, log_dir=tmp)
    texts = dict(zip(modules, procs, strict=True))

    def get(module: str) -> str:
        proc = texts[module]
        assert proc.returncode == 0, proc.stderr[-3000:]
        return proc.stdout

    return get


@pytest.fixture(scope="session")
def real_data_dir(archives, tmp_path_factory) -> Path:
    """A writable data_dir where the real archives are unpacked and parsed once per session.
    MOTION_DATA_DIR, when set, is reused so repeated local runs skip the unpacking."""
    reuse = os.environ.get("MOTION_DATA_DIR")
    return Path(reuse) if reuse else tmp_path_factory.mktemp("real_data")


@pytest.fixture
def dynamo_only(monkeypatch):
    """torch.compile through Dynamo alone (backend "eager"): the graphs, guards and limits on
    recompiling are torch's own, without inductor's code generation (a minute per model on
    the CPU). Starts from a fresh compiler state: graphs of earlier tests count against the
    same limits."""
    import torch

    compile_ = torch.compile

    def compile_with_dynamo_only(fn, *, mode=None, **kwargs):
        return compile_(fn, backend="eager", **kwargs)

    torch.compiler.reset()
    monkeypatch.setattr(torch, "compile", compile_with_dynamo_only)
    yield
    torch.compiler.reset()
