"""Ctrl-C on a 2-worker sweep: once (grace, then exit 130, trials kept) and twice (at once); no orphans."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from benchmark.common.store import ResultStore, load_results

SLOW = Path(__file__).parent / "data" / "slow_sweep.toml"
BENCH = [sys.executable, "-m", "benchmark.cli"]


def _interruptible() -> None:
    """In the child: Ctrl-C at its default. A shell runs a background job (`pytest &` in a script) with SIGINT
    ignored, and the child would inherit that, as a terminal's background job rightly does."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(results: Path) -> tuple[subprocess.Popen, list[psutil.Process]]:
    proc = subprocess.Popen([*BENCH, "sweep", str(SLOW), "--workers", "2", "--results", str(results)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    children: list[psutil.Process] = []
    while time.monotonic() < deadline:  # both workers running a trial
        children = psutil.Process(proc.pid).children(recursive=True)
        busy = [c for c in children if c.cpu_times().user > 3.0]
        if len(busy) >= 2:
            break
        time.sleep(0.2)
    assert len(children) >= 2, "the workers never started"
    return proc, children


def _finish(proc: subprocess.Popen, children: list[psutil.Process], limit_s: float) -> tuple[float, str]:
    start = time.monotonic()
    _, err = proc.communicate(timeout=120)
    took = time.monotonic() - start
    time.sleep(0.5)
    alive = [c for c in children if c.is_running() and c.status() != psutil.STATUS_ZOMBIE]
    assert not alive, f"orphaned: {[c.cmdline()[:3] for c in alive]}"
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert took < limit_s, f"took {took:.1f} s to exit"
    return took, err


@pytest.mark.slow
@pytest.mark.parametrize("signals, limit_s", [(1, 5.0 + 8.0), (2, 4.0)])
def test_ctrl_c_on_a_sweep_exits_130_with_no_orphans_and_keeps_what_finished(tmp_path, signals, limit_s):
    results = tmp_path / "store"
    proc, children = _start(results)
    for _ in range(signals):
        os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole group
        time.sleep(0.3)
    took, err = _finish(proc, children, limit_s)
    assert "interrupted" in err and "run the same command again to resume" in err
    if signals == 2:
        return  # what is kept is the same after either; once is enough
    kept = ResultStore(results).done_ids()  # finished trials, whole: the same command would run only the others
    listed = subprocess.run([*BENCH, "sweep", str(SLOW), "--workers", "2", "--results", str(results), "--dry-run"],
                            capture_output=True, text=True, timeout=120)
    assert listed.returncode == 0, listed.stderr
    assert f"4 trials, {4 - len(kept)} missing" in listed.stdout  # running them: test_sweep's killed-sweep test
    if kept:
        assert len(load_results(results)) == len(kept)


@pytest.mark.slow
def test_ctrl_c_to_the_driver_alone_ends_its_workers(tmp_path):
    proc, children = _start(tmp_path / "store")
    os.kill(proc.pid, signal.SIGINT)
    _finish(proc, children, 5.0 + 8.0)


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_sigterm_or_sighup_to_a_sweep_ends_it_and_its_workers(tmp_path, signum):
    """A process manager's SIGTERM or a closed terminal's SIGHUP, to the driver alone: out within 3 s."""
    proc, children = _start(tmp_path / "store")
    os.kill(proc.pid, signum)
    _finish(proc, children, 3.0)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_sigterm_or_sighup_to_bench_view_web_ends_the_viewer(tmp_path, signum):
    import socket
    import urllib.request

    path = tmp_path / "walk.rrd"
    made = subprocess.run([*BENCH, "run", "--policy", "stand", "--trials", "1", "--duration", "0.5", "--record",
                           str(path)], capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    view = subprocess.Popen([*BENCH, "view", str(path), "--web", "--port", str(port)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    deadline, serving = time.monotonic() + 60, False
    while time.monotonic() < deadline and not serving:
        try:
            serving = urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2).status == 200
        except OSError:
            time.sleep(0.5)
    assert serving, "the web viewer never answered"
    viewers = [c for c in psutil.Process(view.pid).children(recursive=True)]
    assert viewers, "bench view started no viewer"
    os.kill(view.pid, signum)
    view.communicate(timeout=10)
    time.sleep(3)
    alive = [c for c in viewers if c.is_running() and c.status() != psutil.STATUS_ZOMBIE]
    assert not alive, f"outlived bench view: {[c.cmdline()[:3] for c in alive]}"


def test_a_signal_mid_llama_cpp_read_lands_at_once():
    """llama.cpp releases the GIL while it reads, so a Ctrl-C (here SIGALRM's handler) interrupts the wait within
    a step instead of after the read; the request is abandoned with its server, for `leave` to end the process."""
    from benchmark.llm.models import ABANDONED, Constraint, EmbeddedModel, Sampling, settle_abandoned

    model = EmbeddedModel(threads=1, context=8192, draft="none")
    prompt = " ".join(str(i % 997) for i in range(1000))  # ~4,000 tokens: a cold read of seconds on a fast core
    fired: list[float] = []

    def interrupt(signum, frame):
        fired.append(time.monotonic())
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGALRM, interrupt)
    signal.setitimer(signal.ITIMER_REAL, 0.5)
    try:
        with pytest.raises(KeyboardInterrupt):
            model.complete(prompt, Sampling(max_tokens=4), Constraint(), cold=True)
        landed = time.monotonic()
        assert fired and landed - fired[0] < 1.0, "the interrupt waited for llama.cpp"
        assert [not done.is_set() for _, done in ABANDONED] == [True], "the read ended before the signal"
        assert model._server is None
        model.close()  # nothing left to stop; must not wait for the read
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        settle_abandoned()
    assert not ABANDONED


@pytest.mark.parametrize("after_s, limit_s", [(0.3, 15.0), (8.0, 3.0)], ids=["while-loading", "mid-query"])
def test_ctrl_c_on_bench_eval_mid_probe_exits_130_in_a_line(tmp_path, after_s, limit_s):
    """`bench eval` had no handler: a Ctrl-C mid-probe waited for llama.cpp, then printed a traceback. A Ctrl-C while
    llama.cpp loads the model left a server no one held, whose destructor waited for ever: it now waits for the load
    (seconds) and ends the same way."""
    proc = subprocess.Popen([*BENCH, "eval", "--llm", "embedded", "--store", str(tmp_path / "board"), "--threads",
                             "1", "--no-cache"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_interruptible)
    first = proc.stderr.readline()  # printed just before the model loads and the first walk is asked
    assert first.startswith("bench: probe"), first
    time.sleep(after_s)  # 0.3 s: llama.cpp is loading; 8 s: a query in flight (seconds; the loop's rest microseconds)
    proc.send_signal(signal.SIGINT)
    start = time.monotonic()
    _, err = proc.communicate(timeout=60)
    took = time.monotonic() - start
    assert proc.returncode == 130, err
    assert "Traceback" not in err and err.strip().splitlines()[-1] == (
        "bench: interrupted: everything finished is stored; run the same command again to resume"), err
    assert took < limit_s, f"took {took:.1f} s to exit"
