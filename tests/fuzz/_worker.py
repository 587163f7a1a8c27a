"""The fuzz runner's worker process: one process runs case after case through
``needlenet.cli.main``, bounded in time and memory.

Importing numpy, OpenCV, onnxruntime and the trackers takes seconds, so one worker process
(``python -m tests.fuzz.runner --worker``, started by :class:`Worker`) runs case after case
in-process:
``main(argv)`` with stdout and stderr captured (Python's and, for what C libraries print, file
descriptors 1 and 2), its working directory the case's own. After imports and one warm-up
case it caps its data segment (``RLIMIT_DATA``) at what it then uses plus 2 GiB. RLIMIT_DATA
rather than RLIMIT_AS because onnxruntime's thread pools and glibc's per-thread malloc arenas
reserve address space they never touch: measured here, the warmed worker (numpy, OpenCV,
onnxruntime, pynrrd and every tracker imported, one learned in-plane case run) has a VmSize
of 977 MB against a VmData of 446 MB (RSS 216 MB), and the reservations grow with the threads
a case starts, so a cap on address space would fail cases for memory nobody used.
Since Linux 4.7 RLIMIT_DATA counts every private writable mapping, which is where numpy's,
OpenCV's and onnxruntime's large buffers live (the worker runs with ``MALLOC_ARENA_MAX=2`` so
that glibc's per-thread arenas stay few). Without the cap a bad case could take the machine's
memory; with it an allocation past 2 GiB fails inside the case, which is what is counted.
Each case also has its resident peak measured (VmHWM, reset through ``/proc/self/clear_refs``
before it).

**Time.** Each case has ``--time-limit`` seconds (20 by default): an interval timer raises in
the worker (reporting where it was), and if the worker does not answer 15 s later (stuck in C
code) the parent kills it. A worker that dies or is killed is replaced and the run goes on;
after a hang, a memory failure or a crash, and every 250 cases, it is replaced anyway so that
no case inherits another's state or its memory.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import select
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

__all__ = ["HARD_GRACE_S", "MEM_EXTRA", "TIME_LIMIT_S", "Worker", "worker_main"]

TIME_LIMIT_S = 20.0
HARD_GRACE_S = 15.0
MEM_EXTRA = 2 << 30


class _CaseTimeout(BaseException):
    """Raised in the worker when a case runs over its time limit (a BaseException, so that no
    ``except Exception`` in the code under test swallows it)."""


def _status_kb(field: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    return 0


def _reset_peak() -> None:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _run_in_worker(argv, cwd, noise_path, time_limit) -> dict:
    from needlenet.cli import main

    os.chdir(cwd)
    out, err = io.StringIO(), io.StringIO()
    saved = os.dup(1), os.dup(2)
    fd = os.open(noise_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    rss0 = _status_kb("VmRSS")
    _reset_peak()
    res: dict = {"rc": None, "exc": None, "tb": None}
    t0 = time.perf_counter()

    def on_alarm(signum, frame):
        raise _CaseTimeout()

    signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, time_limit)
    try:
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                res["rc"] = main(list(argv))
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
    except SystemExit as exc:
        code = exc.code
        if code is None:
            res["rc"] = 0
        elif isinstance(code, int):
            res["rc"] = code
        else:
            err.write(str(code) + "\n")
            res["rc"] = 1
    except _CaseTimeout:
        res["exc"] = "timeout"
        res["tb"] = "".join(traceback.format_exc(limit=-8))
    except MemoryError:
        res["exc"] = "MemoryError"
        res["tb"] = "".join(traceback.format_exc(limit=-8))
    except BaseException as exc:  # everything else out of main is a traceback
        res["exc"] = f"{type(exc).__name__}: {str(exc)[:300]}"
        res["tb"] = "".join(traceback.format_exc(limit=-8))
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        os.close(saved[0])
        os.close(saved[1])
        os.chdir("/")
    res["wall_s"] = time.perf_counter() - t0
    res["peak_rss_mb"] = (_status_kb("VmHWM") - rss0) / 1024.0
    res["vmdata_mb"] = _status_kb("VmData") / 1024.0
    res["stdout"] = out.getvalue()[-20000:]
    res["stderr"] = err.getvalue()[-8000:]
    with open(noise_path, errors="replace") as fh:
        res["noise"] = fh.read()[-4000:]
    return res


def worker_main(rfd: int, wfd: int) -> None:
    """The worker's loop: one JSON request per line on ``rfd``, one JSON answer on ``wfd``."""
    import faulthandler
    import resource

    faulthandler.enable(file=sys.__stderr__, all_threads=False)
    rx = os.fdopen(rfd, "r")
    tx = os.fdopen(wfd, "w")
    import cv2  # noqa: F401
    import nrrd  # noqa: F401
    import numpy  # noqa: F401
    import onnxruntime  # noqa: F401

    import needlenet.cli  # noqa: F401
    from needlenet.trackers._registry import TRACKERS, tracker_methods

    for name in TRACKERS:  # every tracker module, imported once
        tracker_methods(name)

    for line in rx:
        msg = json.loads(line)
        if msg["cmd"] == "quit":
            break
        res = _run_in_worker(msg["argv"], msg["cwd"], msg["noise"], msg["time_limit"])
        if msg["cmd"] == "warmup":
            base = _status_kb("VmData") * 1024
            limit = base + int(msg["mem_extra"])
            resource.setrlimit(resource.RLIMIT_DATA, (limit, resource.RLIM_INFINITY))
            res.update(baseline_vmdata_mb=base / 2**20, vmsize_mb=_status_kb("VmSize") / 1024,
                       rss_mb=_status_kb("VmRSS") / 1024, limit_mb=limit / 2**20)
        tx.write(json.dumps(res) + "\n")
        tx.flush()


class Worker:
    """The parent's handle on a worker process: start, warm up, run a case, kill."""

    def __init__(self, workdir: Path, warm_argv: list[str], warm_cwd: Path,
                 time_limit: float = TIME_LIMIT_S, mem_extra: int = MEM_EXTRA):
        self.workdir = Path(workdir)
        self.time_limit = time_limit
        self.noise = self.workdir / f"noise-{os.getpid()}.txt"
        r1, w1 = os.pipe()
        r2, w2 = os.pipe()
        env = dict(os.environ, MALLOC_ARENA_MAX="2", PYTHONFAULTHANDLER="1")
        root = Path(__file__).resolve().parents[2]
        env["PYTHONPATH"] = os.pathsep.join([str(root), env.get("PYTHONPATH", "")]).rstrip(
            os.pathsep)
        self.log = open(self.workdir / "worker.log", "ab")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tests.fuzz.runner", "--worker", str(r1), str(w2)],
            pass_fds=(r1, w2), stdin=subprocess.DEVNULL, stdout=self.log, stderr=self.log,
            env=env, cwd=str(root))
        os.close(r1)
        os.close(w2)
        self.tx = os.fdopen(w1, "w")
        self.rx = r2
        self.buf = b""
        self.cases = 0
        self.info = self.request({"cmd": "warmup", "argv": warm_argv, "cwd": str(warm_cwd),
                                  "mem_extra": mem_extra}, timeout=300.0)
        if self.info is None or self.info.get("rc") != 0:
            raise RuntimeError(f"fuzz worker failed to warm up: {self.info}; see "
                               f"{self.workdir / 'worker.log'}")

    def request(self, msg: dict, timeout: float) -> dict | None:
        """Send a request; its answer, or None when the worker died or ran past ``timeout``."""
        msg = {"noise": str(self.noise), "time_limit": self.time_limit, **msg}
        try:
            self.tx.write(json.dumps(msg) + "\n")
            self.tx.flush()
        except (BrokenPipeError, OSError):
            return None
        deadline = time.monotonic() + timeout
        while b"\n" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([self.rx], [], [], left)
            if not ready:
                continue
            chunk = os.read(self.rx, 1 << 20)
            if not chunk:
                return None
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        self.cases += 1
        return json.loads(line)

    def run(self, argv, cwd) -> dict | None:
        return self.request({"cmd": "case", "argv": argv, "cwd": str(cwd)},
                            timeout=self.time_limit + HARD_GRACE_S)

    def noise_text(self) -> str:
        try:
            return self.noise.read_text(errors="replace")[-4000:]
        except OSError:
            return ""

    def close(self, kill: bool = False) -> int | None:
        """Stop the worker (SIGKILL when ``kill``); its exit status."""
        if self.proc.poll() is None:
            if kill:
                self.proc.kill()
            else:
                try:
                    self.tx.write(json.dumps({"cmd": "quit"}) + "\n")
                    self.tx.flush()
                except OSError:
                    pass
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for closer in (self.tx.close, lambda: os.close(self.rx), self.log.close):
            with contextlib.suppress(OSError):
                closer()
        return self.proc.returncode
