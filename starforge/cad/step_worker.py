"""The STEP half of an export, in a process of its own beside the meshes.

OpenCascade's booleans hold Python's global interpreter lock, so a second *thread* building
the STEP solids stalls the mesh work it was meant to overlap; a second *process* runs on the
second core.  :func:`start` launches ``python -c`` with this module's :func:`main`, hands it the
job (body descriptions, printing transforms, colours, plate layouts, the stage folder) as one
pickle on stdin, and reads one line per finished file back.  The worker writes each body's
``<name>.step`` in order, then each plate's, all into the caller's staged folder; the caller
kills it when the export leaves early, so no file is begun into a stage being removed.  Every
run writes the same files in the same order in a fresh process: OCCT numbers some STEP entities
with a process-wide counter, so this also keeps the files the same from run to run.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from starforge.errors import StarforgeError

_BOOT = (
    "import sys\n"
    "if sys.argv[1] not in sys.path: sys.path.insert(0, sys.argv[1])\n"
    "from starforge.cad.step_worker import main\n"
    "main()\n"
)


def run_job(job: dict, say) -> None:
    """Build and write every STEP file of ``job``; ``say(line)`` after each (``body i volume``
    per body, ``plate name`` per plate)."""
    from starforge.cad.occ import assembly, body_solid, placed, write_step

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
    """Worker entry: the job from stdin (pickle), progress lines to stdout, ``error <message>``
    and exit status 1 for a StarforgeError (a traceback on stderr for anything else).  The
    kernel is loaded first, while the caller may still be describing the job; an empty stdin
    (the caller changed its mind) ends the worker quietly."""
    import os

    # the protocol gets the original stdout to itself; anything the kernel prints there (C++
    # streams) goes to stderr, which the caller keeps for an error message
    out = os.fdopen(os.dup(sys.stdout.fileno()), "w", encoding="utf-8")
    sys.stdout.flush()
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())

    import OCP.TopoDS  # noqa: F401  (OCP's one large extension module: most of the import time)

    import starforge.cad.occ  # noqa: F401

    data = sys.stdin.buffer.read()
    if not data:
        return
    job = pickle.loads(data)

    def say(line: str) -> None:
        out.write(line + "\n")
        out.flush()

    try:
        run_job(job, say)
    except StarforgeError as exc:
        say("error " + str(exc).replace("\n", " "))
        _leave(1)
    say("done")
    _leave(0)


def _leave(code: int) -> None:
    """Exit now, without the interpreter's clean-up: tearing down OCP's thousands of bound
    classes and OCCT's static objects takes 0.25-0.3 s of CPU, and the caller waits for the
    exit.  Every STEP file is closed by then (OCCT closes each as it returns), and so is the
    protocol's last line (flushed by ``say``)."""
    import os

    sys.stderr.flush()
    os._exit(code)


class StepProcess:
    """A STEP worker: launched at once (it loads the kernel), given its job by :meth:`send`;
    :meth:`result` waits for it, :meth:`kill` ends it early.  A context manager: leaving the
    ``with`` block ends a worker that has not finished (harmless after :meth:`result`)."""

    def __init__(self) -> None:
        import starforge

        root = str(Path(starforge.__file__).resolve().parent.parent)
        self.t0 = time.perf_counter()
        self.volumes: list = []
        self.error = ""
        self.finished = False
        self.sent = False
        self.tick = None
        self.stderr = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _BOOT, root],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.stderr,
        )
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
        try:
            self.proc.stdin.write(pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL))
            self.proc.stdin.close()
        except OSError:  # the worker died at once: result() says why
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
        self.reader.join()
        for f in (self.proc.stdin, self.proc.stdout, self.stderr):
            if not f.closed:
                f.close()


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
