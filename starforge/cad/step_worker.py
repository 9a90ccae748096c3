"""The STEP half of an export, in a process of its own beside the meshes.

OpenCascade's booleans hold Python's global interpreter lock, so a second *thread* building
the STEP solids stalls the mesh work it was meant to overlap; a second *process* runs on the
second core.  :class:`StepProcess` forks that process where it can (:func:`starforge.runtime.procs.can_fork`,
and only while this process has not loaded OCP itself): the child starts with numpy and the body
code already imported and loads only the kernel.  Elsewhere it launches ``python -c`` with this
module's :func:`main`.  Either way the worker gets the job (body descriptions, printing
transforms, colours, plate layouts, the stage folder) as one pickle through a pipe, and sends one
line per finished file back.  The worker writes each body's ``<name>.step`` in order, then each
plate's, all into the caller's staged folder; the caller kills it when the export leaves early,
so no file is begun into a stage being removed.  Every run writes the same files in the same
order in a process whose kernel is fresh: OCCT numbers some STEP entities with a process-wide
counter, so this also keeps the files the same from run to run.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from starforge.cad.brep import assembly, body_solid, kernel, placed, write_step
from starforge.errors import StarforgeError
from starforge.runtime.procs import adopt, fork_helper, release

_BOOT = (
    "import sys\n"
    "if sys.argv[1] not in sys.path: sys.path.insert(0, sys.argv[1])\n"
    "from starforge.cad.step_worker import main\n"
    "main()\n"
)


def run_job(job: dict, say) -> None:
    """Build and write every STEP file of ``job``; ``say(line)`` after each (``body i volume``
    per body, ``plate name`` per plate)."""
    stage = Path(job["stage"])
    solids = []
    for i, (b, T, colour) in enumerate(zip(job["bodies"], job["transforms"], job["colours"], strict=True)):
        solid = placed(body_solid(b), T, b.name, colour)
        write_step(solid, stage / f"{b.name}.step")
        solids.append(solid)
        say(f"body {i} {solid.volume!r}")
    for name, members, transforms in job["plates"]:
        write_step(assembly([solids[i] for i in members], transforms, name), stage / f"{name}.step")
        say(f"plate {name}")


def main() -> None:
    """Entry of a launched worker (``python -c``): the job from stdin (pickle), progress lines
    to stdout; see :func:`_serve`."""
    import os

    # the protocol gets the original stdout to itself; anything the kernel prints there (C++
    # streams) goes to stderr, which the caller keeps for an error message
    out = os.fdopen(os.dup(sys.stdout.fileno()), "w", encoding="utf-8")
    sys.stdout.flush()
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    _leave(_serve(sys.stdin.buffer, out))


def _serve(job_in, out) -> int:
    """Load the kernel, read the job from ``job_in`` (binary file, pickle), build and write it,
    saying each step on ``out`` (text file); the exit status: 0 when every file was written,
    1 after ``error <message>`` for a StarforgeError (anything else propagates: a traceback on
    stderr).  The kernel is loaded first, while the caller may still be describing the job; an
    empty job (the caller changed its mind) ends the worker quietly, status 0."""
    kernel()  # build123d and OCP under it: most of the worker's start-up

    data = job_in.read()
    if not data:
        return 0
    job = pickle.loads(data)

    def say(line: str) -> None:
        out.write(line + "\n")
        out.flush()

    try:
        run_job(job, say)
    except StarforgeError as exc:
        say("error " + str(exc).replace("\n", " "))
        return 1
    say("done")
    return 0


def _leave(code: int) -> None:
    """Exit now, without the interpreter's clean-up: tearing down OCP's thousands of bound
    classes and OCCT's static objects takes 0.25-0.3 s of CPU, and the caller waits for the
    exit.  Every STEP file is closed by then (OCCT closes each as it returns), and so is the
    protocol's last line (flushed by ``say``)."""
    import os

    sys.stderr.flush()
    os._exit(code)


def _forked_child(job_fd: int, out_fd: int, err_fd: int) -> None:
    """Body of a forked worker; never returns.  Python's own SIGINT / SIGTERM handling instead
    of the parent's (whose handlers would note an interrupt of the parent's command), stdout
    and stderr into the caller's error file (the kernel's C++ output included), then
    :func:`_serve`; any exception ends it with status 1 (its traceback in the error file)."""
    import os

    code = 1
    try:
        os.dup2(err_fd, 2)
        os.dup2(err_fd, 1)
        with os.fdopen(job_fd, "rb") as job_in, os.fdopen(out_fd, "w", encoding="utf-8") as out:
            code = _serve(job_in, out)
    except BaseException:
        try:
            import traceback

            traceback.print_exc()
        except BaseException:
            pass
    finally:
        _leave(code)


class _Forked:
    """What :class:`StepProcess` uses of :class:`subprocess.Popen`, for a forked worker: the
    job's pipe (``stdin``), the protocol's (``stdout``), :meth:`poll`, :meth:`wait`, :meth:`kill`
    and ``returncode`` (negative: the signal that ended it)."""

    def __init__(self, stderr) -> None:
        import os

        job_r, job_w = os.pipe()
        out_r, out_w = os.pipe()
        sys.stdout.flush()  # nothing buffered here is written twice
        sys.stderr.flush()
        pid = fork_helper(default_handlers=True)
        if pid == 0:
            os.close(job_w)
            os.close(out_r)
            _forked_child(job_r, out_w, stderr.fileno())
        os.close(job_r)
        os.close(out_w)
        self.pid = pid
        self.returncode: int | None = None
        self.stdin = os.fdopen(job_w, "wb")
        self.stdout = os.fdopen(out_r, "rb")

    def _reaped(self, flags: int) -> int | None:
        import os

        if self.returncode is None:
            pid, status = os.waitpid(self.pid, flags)
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
                release(self.pid)
        return self.returncode

    def poll(self) -> int | None:
        import os

        return self._reaped(os.WNOHANG)

    def wait(self) -> int:
        return self._reaped(0)

    def kill(self) -> None:
        import os
        import signal

        if self.returncode is None:  # not reaped yet: the pid is still this worker's
            os.kill(self.pid, signal.SIGKILL)


class StepProcess:
    """A STEP worker: started at once (it loads the kernel), given its job by :meth:`send`;
    :meth:`result` waits for it, :meth:`kill` ends it early.  A context manager: leaving the
    ``with`` block ends a worker that has not finished (harmless after :meth:`result`).

    ``fork``: True forks this process (ValueError when OCP is loaded here), False launches a
    fresh interpreter, None (default) forks where :func:`starforge.runtime.procs.can_fork` allows
    and OCP is not loaded here (``forked`` says which).  The files are the same bytes either way."""

    def __init__(self, fork: bool | None = None) -> None:
        import starforge

        # a kernel loaded here would be the child's too: its STEP counters advanced, and the
        # thread pool its parallel booleans started here gone (a child's boolean waits forever)
        if fork and "OCP" in sys.modules:
            raise ValueError("StepProcess(fork=True) with OCP loaded in this process; pass fork=False or None")

        root = str(Path(starforge.__file__).resolve().parent.parent)
        self.t0 = time.perf_counter()
        self.volumes: list = []
        self.error = ""
        self.finished = False
        self.sent = False
        self.tick = None
        self.stderr = tempfile.TemporaryFile()
        if fork is None:
            from starforge.runtime.procs import can_fork

            fork = can_fork() and "OCP" not in sys.modules
        self.forked = bool(fork)
        if self.forked:
            self.proc = _Forked(self.stderr)
        else:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", _BOOT, root],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=self.stderr,
            )
            adopt(self.proc.pid)  # ended with the command (starforge.runtime.procs.end_children)
        self.writer: threading.Thread | None = None
        self.reader = threading.Thread(target=self._read, name="starforge-step", daemon=True)
        self.reader.start()

    def __enter__(self) -> StepProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.kill()

    def send(self, job: dict, tick=None) -> None:
        """Hand the worker its job (see :func:`start`); ``tick()`` after each body's file."""
        self.volumes = [None] * len(job["bodies"])
        self.tick = tick
        self.sent = True
        # from a thread: a job larger than the pipe's buffer (25 bodies: 70 kB, over Linux's
        # 64 kB) would otherwise hold this process until the worker reads it, after its kernel
        # has loaded (0.5-0.6 s that the meshes would wait)
        data = pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL)
        self.writer = threading.Thread(target=self._write, args=(data,), name="starforge-step-job", daemon=True)
        self.writer.start()

    def _write(self, data: bytes) -> None:
        try:
            self.proc.stdin.write(data)
            self.proc.stdin.close()
        except (OSError, ValueError):  # the worker died or was killed: result() says why
            pass

    def _read(self) -> None:
        for raw in self.proc.stdout:
            kind, _, rest = raw.decode("utf-8", "replace").rstrip("\n").partition(" ")
            if kind == "body":
                i, vol = rest.split(" ")
                self.volumes[int(i)] = float(vol)
                if self.tick is not None:
                    self.tick()
            elif kind == "error":
                self.error = rest
            elif kind == "done":
                self.finished = True

    def result(self) -> tuple[list[float], float]:
        """(volumes of the bodies' solids, mm^3, in order; seconds from launch to end)."""
        if not self.sent:
            raise RuntimeError("result() before send(): the worker has no job")
        code = self.proc.wait()
        release(self.proc.pid)
        self.writer.join()
        self.reader.join()
        self.proc.stdout.close()
        seconds = time.perf_counter() - self.t0
        if code != 0 or not self.finished:
            if self.error:
                self.stderr.close()
                raise StarforgeError(self.error)
            self.stderr.seek(0)
            lines = self.stderr.read().decode("utf-8", "replace").strip().splitlines()
            self.stderr.close()
            raise StarforgeError(f"STEP export failed (exit status {code}): {lines[-1] if lines else 'no message'}")
        self.stderr.close()
        if any(v is None for v in self.volumes):
            raise StarforgeError("STEP export failed: the worker did not report every body")
        return self.volumes, seconds

    def kill(self) -> None:
        """End the worker now (harmless once it has finished)."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        release(self.proc.pid)
        if self.writer is not None:  # its write fails once the worker is gone
            self.writer.join()
        self.reader.join()
        for f in (self.proc.stdin, self.proc.stdout, self.stderr):
            if not f.closed:
                f.close()


#: the worker :func:`start_early` launched, until :func:`launch` hands it out
_early: list[StepProcess] = []


def start_early() -> None:
    """Launch a worker now for the next :func:`launch` to hand out: the console script calls
    this before it loads the command line's modules when the command asks for STEP files, so
    that the worker's kernel loads meanwhile.  A worker nobody takes ends with the command
    (:func:`starforge.runtime.procs.end_children`)."""
    if not _early:
        _early.append(StepProcess())


def launch() -> StepProcess:
    """The worker :func:`start_early` launched, else a new one."""
    return _early.pop() if _early else StepProcess()


def job_for(bodies, transforms, colours, stage, plates=()) -> dict:
    """The worker's job: ``bodies`` (:class:`~starforge.cad.body.Body`), their printing
    ``transforms`` (4, 4), ``colours`` ((r, g, b) 0..255), the ``stage`` folder to write into,
    and per plate (name, member indices, (4, 4) bed transforms)."""
    return {
        "bodies": list(bodies),
        "transforms": [[list(map(float, row)) for row in T] for T in transforms],
        "colours": [tuple(int(c) for c in col) for col in colours],
        "stage": str(stage),
        "plates": [
            (name, list(members), [[list(map(float, row)) for row in T] for T in ts]) for name, members, ts in plates
        ],
    }


def start(bodies, transforms, colours, stage, plates=(), tick=None, worker: StepProcess | None = None) -> StepProcess:
    """Launch a worker (or use ``worker``, launched earlier) and hand it the job of
    :func:`job_for`; ``tick()`` after each body's file."""
    worker = worker if worker is not None else StepProcess()
    worker.send(job_for(bodies, transforms, colours, stage, plates), tick)
    return worker
