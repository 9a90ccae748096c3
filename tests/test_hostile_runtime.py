"""Hostile runtime: endpoints that are not a dask cluster, clusters that lose their workers,
signals at any moment, names that collide, numbers that only look like numbers.

The CLI cases run in a child process of their own session (``tests.test_hostile_inputs.run_child``)
with a time budget; each asserts one line and exit 2 (or the signal's code), nothing written, no
traceback or third-party warning on stderr, and no process left in the session.
"""

from __future__ import annotations

import contextlib
import http.server
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from starforge.errors import StarforgeError
from starforge.io import INPUT_LIMITS, check_input_file, check_name
from starforge.props.batch import jobs
from starforge.runtime import address, engine
from starforge.tracking.formats._common import num
from tests.test_hostile_inputs import CHILD, left_in_session, run_child, snapshot

#: the issue's bound: --scheduler at anything that is not a working dask cluster answers within it
SCHEDULER_BUDGET_S = 15.0


# --- the scheduler address ---------------------------------------------------------------------


@pytest.mark.parametrize(
    "text, want",
    [
        ("10.0.0.1", "tcp://10.0.0.1:8786"),
        ("tcp://10.0.0.1:9000", "tcp://10.0.0.1:9000"),
        ("TCP://node-7.cluster.local:1", "tcp://node-7.cluster.local:1"),
        ("[::1]:8786", "tcp://[::1]:8786"),
        ("tcp://[fe80::1]", "tcp://[fe80::1]:8786"),
        ("localhost:65535", "tcp://localhost:65535"),
    ],
)
def test_accepted_addresses_are_canonical(text, want):
    assert address.parse_address(text) == want
    assert address.parse_address(want) == want  # canonical forms are fixed points


@pytest.mark.parametrize(
    "text, why",
    [
        ("tls://h:8786", "tls:// is not supported"),
        ("ucx://h:8786", "ucx:// is not supported"),
        ("inproc://x", "inproc:// is not supported"),
        ("tcp://127.0.0.1:abc", "the port must be a number from 1 to 65535, got 'abc'"),
        ("h:" + "9" * 5000, "the port must be a number"),
        ("h:65536", "the port must be a number"),
        ("h:0", "the port must be a number"),
        ("h:-1", "the port must be a number"),
        ("h:８７８６", "the port must be a number"),  # full-width digits: int() would take them
        ("::1", "an IPv6 address goes in brackets"),
        ("[zz]:1", "is not an IPv6 address"),
        ("a b:1", "not a scheduler address"),
        ("tcp://h:1/path", "not a scheduler address"),
        ("user@h:1", "not a scheduler address"),
        ("-h:1", "is not a host name"),
        ("", "not a scheduler address"),
    ],
)
def test_refused_addresses_name_the_accepted_forms(text, why):
    with pytest.raises(StarforgeError) as exc:
        address.parse_address(text)
    msg = str(exc.value)
    assert why in msg and "expected tcp://HOST:PORT, HOST:PORT or HOST" in msg
    assert "\n" not in msg and len(msg) < 300


# --- endpoints that are not a dask scheduler --------------------------------------------------


@contextlib.contextmanager
def not_dask_endpoints():
    """Listeners that are not dask schedulers: one that never answers, an HTTP server, one that
    sends other bytes and hangs up; and a port nothing listens on."""
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(16)

    class Quiet(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            self.send_response(200)
            self.end_headers()

        do_HEAD = do_GET

        def log_message(self, *args):
            pass

    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    chatty = socket.socket()
    chatty.bind(("127.0.0.1", 0))
    chatty.listen(16)

    def banner():
        while True:
            try:
                conn, _ = chatty.accept()
            except OSError:
                return
            with conn:
                conn.sendall(b"SSH-2.0-OpenSSH_9.6\r\n")

    threading.Thread(target=banner, daemon=True).start()
    free = socket.socket()
    free.bind(("127.0.0.1", 0))
    closed = free.getsockname()[1]
    free.close()
    try:
        yield {
            "silent": f"127.0.0.1:{silent.getsockname()[1]}",
            "http": f"127.0.0.1:{httpd.server_address[1]}",
            "other-bytes": f"127.0.0.1:{chatty.getsockname()[1]}",
            "closed": f"127.0.0.1:{closed}",
        }
    finally:
        httpd.shutdown()
        httpd.server_close()
        silent.close()
        chatty.close()


@pytest.fixture(scope="module")
def endpoints():
    with not_dask_endpoints() as ends:
        yield ends


@pytest.mark.parametrize(
    "kind, message",
    [
        ("silent", r"is not a dask scheduler: something accepts connections there but sent no dask handshake"),
        ("http", r"is not a dask scheduler: an HTTP server answers there"),
        ("other-bytes", r"is not a dask scheduler: it answered 'SSH-2.0-OpenSSH_9.6', not dask's handshake"),
        ("closed", r"cannot reach the dask scheduler at .*: nothing listens there"),
    ],
)
def test_the_probe_names_what_answers_instead(endpoints, kind, message):
    t0 = time.perf_counter()
    with pytest.raises(StarforgeError, match=message):
        address.probe(address.parse_address(endpoints[kind]), timeout_s=2.0, handshake_s=0.5)
    assert time.perf_counter() - t0 < 2.0 + 0.5 + 1.0 + 1.0  # connect, handshake, the HTTP question, slack


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["silent", "http", "other-bytes", "closed"])
@pytest.mark.parametrize("command", ["sweep", "stars", "place-batch"])
def test_scheduler_at_a_non_dask_endpoint_is_one_line_within_15_s(endpoints, kind, command, tmp_path):
    args = {
        "sweep": ["sweep", "--delta", "3", "--cube", "18", "--samples", "1000"],
        "stars": ["stars", "--box", "14", "10", "24"],
        "place-batch": ["place-batch", "hammer", "hammer"],
    }[command]
    _one_line_exit_2(args + ["--scheduler", endpoints[kind]], tmp_path, r"dask scheduler")


def _one_line_exit_2(args, tmp_path, pattern, env=None, budget_s=SCHEDULER_BUDGET_S):
    import re

    work = tmp_path / "work"
    out = work / "out"
    out.mkdir(parents=True)
    (out / "keep.txt").write_text("a file the user had")
    before = snapshot(work)
    run = run_child(
        [*args, "--out", str(out)], work, {**os.environ, "OPENBLAS_NUM_THREADS": "1", **(env or {})}, budget_s
    )
    res = run.res
    lines = [line for line in res.stderr.splitlines() if not line.startswith("starforge ")]  # progress lines
    assert res.returncode == 2, res.stderr
    assert len(lines) == 1 and lines[0].startswith("error: ") and re.search(pattern, lines[0]), res.stderr
    assert run.seconds < budget_s
    assert snapshot(work) == before and not run.left


# --- a real dask cluster that fails ------------------------------------------------------------


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def wait_listening(port: int, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def dask_cli(*args) -> subprocess.Popen:
    exe = os.path.join(os.path.dirname(sys.executable), "dask")
    return subprocess.Popen([exe, *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def end_group(*procs) -> None:
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


@pytest.mark.slow
def test_a_scheduler_without_workers_is_one_line(tmp_path):
    pytest.importorskip("distributed")
    port = free_port()
    sched = dask_cli("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard")
    try:
        wait_listening(port)
        _one_line_exit_2(["sweep", "--delta", "3", "--cube", "18", "--samples", "1000", "--scheduler", f"127.0.0.1:{port}"],
                         tmp_path, r"has no workers; start some with `dask worker", budget_s=30.0)
    finally:
        end_group(sched)


@pytest.mark.slow
def test_a_cluster_that_loses_its_only_worker_ends_in_bounded_time(tmp_path):
    """The scheduler would wait for a worker for ever; the run ends NO_WORKERS_S after the last
    one left, with one line and nothing written."""
    pytest.importorskip("distributed")
    port = free_port()
    addr = f"127.0.0.1:{port}"
    sched = dask_cli("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard")
    worker = dask_cli("worker", addr, "--nworkers", "1", "--nthreads", "1", "--no-dashboard")
    work = tmp_path / "work"
    work.mkdir()
    try:
        wait_listening(port)
        from distributed import Client

        with Client(addr, timeout="60s", set_as_default=False) as c:
            c.wait_for_workers(1, timeout=60)
        argv = ["sweep", "--delta", "1:3:0.5", "--cube", "18:30:3", "--samples", "20000", "--scheduler", addr,
                "--out", str(work / "out")]
        with subprocess.Popen([sys.executable, "-c", CHILD, *argv], cwd=work, stderr=subprocess.PIPE, text=True,
                              start_new_session=True) as proc:
            said: list[str] = []
            reader = threading.Thread(target=lambda: said.extend(proc.stderr), daemon=True)
            reader.start()
            deadline = time.monotonic() + 120
            while not any("on the dask cluster" in line for line in said) and time.monotonic() < deadline:
                time.sleep(0.1)  # the cells are submitted: now the only worker goes
            time.sleep(1.0)
            end_group(worker)
            t0 = time.perf_counter()
            proc.wait(timeout=60)
            seconds = time.perf_counter() - t0
            reader.join(5)
        err = "".join(said)
        lines = [line for line in err.splitlines() if not line.startswith(("starforge ", "sweep: "))]
        assert proc.returncode == 2, err
        assert len(lines) == 1 and "nothing was written" in lines[0], err
        assert seconds < engine.NO_WORKERS_S + 15.0
        assert list(work.iterdir()) == [] and not left_in_session(proc.pid)
    finally:
        end_group(worker, sched)


# --- signals: the command and every helper end, nothing staged is left --------------------------

#: a placement that runs far longer than the signals' delays on any machine
PLACE_LONG = ("place", "run", "hammer", "--orientations", "256", "--sites", "2000", "--resolution", "3")


@pytest.mark.slow
@pytest.mark.parametrize(
    "args, delay_s",
    [
        (("stars", "--delta", "1.0"), 4.0),
        (("export", "{family}", "--allow-oversize", "--preview", "--format", "step,stl"), None),
        (PLACE_LONG, 2.5),
        (PLACE_LONG, 4.5),
        (PLACE_LONG, None),  # once staging: while the pictures and the guide are written
        (("check", "{family}", "--frames", "200000"), 4.0),
        # a local dask cluster's worker processes and semaphores (no resource-tracker warning)
        (("sweep", "--delta", "1:3:0.5", "--cube", "18:30:3", "--samples", "20000", "--workers", "2"), 15.0),
    ],
    ids=["stars", "export", "place-early", "place-mid", "place-drawing", "check", "sweep-local-cluster"],
)
@pytest.mark.parametrize("signame", ["SIGTERM", "SIGINT"])
def test_a_signal_ends_the_command_and_its_helpers(args, delay_s, signame, small_family, tmp_path):
    """SIGTERM or SIGINT at several moments: exit within 2 s with the signal's code and one line,
    no process left in the command's session (render and STEP helpers included), no stage."""
    work = tmp_path / "work"
    out = work / "out"
    out.mkdir(parents=True)
    (out / "keep.txt").write_text("a file the user had")
    before = snapshot(work)
    fam = small_family[0] / "family.json"
    argv = [a.format(family=fam) for a in args] + ["--out", str(out), "--force"]
    sig = getattr(signal, signame)
    with subprocess.Popen([sys.executable, "-c", CHILD, *argv], cwd=work, stderr=subprocess.PIPE, text=True,
                          env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, start_new_session=True) as proc:
        try:
            if delay_s is None:  # signalled once the command stages its files
                deadline = time.monotonic() + 60
                while not any(work.glob(".out.*.staging")) and time.monotonic() < deadline:
                    time.sleep(0.02)
            else:
                time.sleep(delay_s)
            if proc.poll() is not None:
                pytest.skip("the work ended before the signal on this machine")
            t0 = time.perf_counter()
            proc.send_signal(sig)
            _, err = proc.communicate(timeout=30)
            seconds = time.perf_counter() - t0
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
    time.sleep(1.5)  # a helper that outlived the command would write (and recreate a stage) by now
    if proc.returncode == 0:  # it exited between the poll above and the signal: no stop to check
        assert "Traceback" not in err and not left_in_session(proc.pid), err
        pytest.skip("the work ended as the signal was sent")
    assert proc.returncode == 128 + sig, err
    assert seconds < 2.0, f"stopped {seconds:.2f} s after {signame}"
    assert "Traceback" not in err and "Warning" not in err, err
    assert not left_in_session(proc.pid)
    assert_stop_line_is_true(err, sig, work, out, before)


def assert_stop_line_is_true(err: str, sig: int, work: Path, out: Path, before: dict) -> None:
    """The stop's one line says what happened to the outputs: nothing changed (the working folder as
    it was), or, for a signal that came while the outputs were being published, that they were
    written to ``out`` (the user's files as they were, new files there, no stage)."""
    word = "terminated" if sig == signal.SIGTERM else "interrupted"
    lines = [line for line in err.splitlines() if not line.startswith(("starforge ", "sweep: "))]  # progress
    after = snapshot(work)
    if lines == [f"{word} after its outputs were written to {out}"]:
        assert {k: after.get(k) for k in before} == before and len(after) > len(before)
        assert not [k for k in after if ".staging" in k or k.endswith(".old")], after.keys()
    else:
        assert lines == [f"{word}; no output was changed"], err
        assert after == before


# --- names, numbers, sizes --------------------------------------------------------------------


@pytest.mark.parametrize(
    "props",
    [
        ["a b.stl", "a_b.stl"],
        ["a b.stl", "a_b.stl", "a_b-2.stl"],
        ["A_B.stl", "a_b.stl", "a b.STL", "a_b-2.stl", "a_b-2-2.obj"],
        ["x" * 150 + ".stl", "x" * 120 + ".obj", "x" * 100 + ".ply"],
        ["hammer", "hammer", "dir/hammer.stl", "./hammer.obj"],
        ["..stl", "-.stl", "é.stl", "把手.stl"],
    ],
)
def test_job_folder_names_never_collide(props):
    for rigs, copies in (([], 1), (["vicon-8", "vicon.8"], 1), ([], 3)):
        names = [n for folders, _ in jobs(props, rigs, "m", "default", 0, copies) for n in folders]
        assert len(names) == len(props) * max(1, len(rigs)) * copies
        assert len({n.casefold() for n in names}) == len(names)  # one folder each, case-insensitively too
        for n in names:
            check_name(n, "job name")


@pytest.mark.parametrize(
    "text, ok",
    [("10", 10.0), ("-1.5e3", -1500.0), (".5", 0.5), ("5.", 5.0), (" 3 ", 3.0),
     ("1_0", None), ("nan", None), ("-inf", None), ("1e999", None), ("0x10", None), ("١٢", None), ("", None)],
)
def test_tracker_numbers_are_plain_decimals(text, ok):
    if ok is None:
        with pytest.raises(StarforgeError, match=r"f: X is not (a number|finite)"):
            num("f", "X", text)
    else:
        assert num("f", "X", text) == ok


@pytest.mark.parametrize("kind", sorted(INPUT_LIMITS))
def test_every_kind_of_input_is_sized_before_it_is_read(kind, tmp_path):
    big = tmp_path / f"big.{kind}"
    with open(big, "wb") as fh:  # sparse: no disk used
        fh.truncate(INPUT_LIMITS[kind] + 1)
    with pytest.raises(StarforgeError, match=rf"big.{kind} is .* above the .* a {kind} input may be"):
        check_input_file(big, "input", kind)
    at_limit = tmp_path / f"ok.{kind}"
    with open(at_limit, "wb") as fh:
        fh.truncate(INPUT_LIMITS[kind])
    assert check_input_file(at_limit, "input", kind) == at_limit


def test_links_that_loop_or_dangle_are_one_line(tmp_path):
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    (tmp_path / "gone").symlink_to(tmp_path / "missing")
    with pytest.raises(StarforgeError, match="loops back on itself"):
        check_input_file(tmp_path / "a", "input")
    with pytest.raises(StarforgeError, match="a symbolic link to a missing file"):
        check_input_file(tmp_path / "gone", "input")
    assert sorted(p.name for p in Path(tmp_path).iterdir()) == ["a", "b", "gone"]


# --- a signal while the CLI's modules load --------------------------------------------------------


@pytest.mark.parametrize("signame, code, word", [("SIGINT", 130, "interrupted"), ("SIGTERM", 143, "terminated")])
def test_a_signal_before_the_command_starts_is_one_line(signame, code, word):
    """The console script sets its signal handlers before it imports the CLI: a signal then (the
    CLI's imports take a large share of a second) ends the process with the one line."""
    script = (
        "import os, signal, time\n"
        "from starforge.runtime.stop import stop_early\n"
        "stop_early()\n"
        f"os.kill(os.getpid(), signal.{signame})\n"
        "time.sleep(30)\n"
    )
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=30)
    assert res.returncode == code
    assert res.stderr.splitlines() == [f"{word}; no output was changed"]


def test_a_signal_before_the_command_starts_ends_the_early_step_worker():
    """The STEP worker the console script launches before the CLI loads ends with a signal that
    comes then: the one line, the signal's code, and no worker left running."""
    script = (
        "import os, signal, sys, time\n"
        "from starforge.runtime.stop import stop_early\n"
        "stop_early()\n"
        "from starforge.cad import step_worker\n"
        "step_worker.start_early()\n"
        "print(step_worker._early[0].proc.pid, flush=True)\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "time.sleep(30)\n"
    )
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert res.returncode == 143
    assert res.stderr.splitlines() == ["terminated; no output was changed"]
    status = Path(f"/proc/{int(res.stdout.split()[0])}/status")
    deadline = time.monotonic() + 10
    while status.exists() and "zombie" not in status.read_text() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not status.exists() or "zombie" in status.read_text()


def test_the_console_script_sets_its_handlers_before_the_cli_loads():
    script = "import sys\nimport starforge.__main__\nprint('starforge.cli' in sys.modules)\n"
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=30)
    assert res.stdout.strip() == "False", res.stderr
    import starforge.__main__ as entry

    src = Path(entry.__file__).read_text()
    assert src.index("stop_early()") < src.index("from starforge.cli import main")


@pytest.mark.parametrize(
    "argv0, orig, expected",
    [
        ("/venv/bin/starforge", ["/venv/bin/python", "/venv/bin/starforge", "stars"], True),
        ("C:/venv/Scripts/starforge.exe", ["python.exe", "C:/venv/Scripts/starforge.exe"], True),
        ("-m", ["python", "-m", "starforge", "stars"], True),
        ("-m", ["python", "-X", "importtime", "-u", "-m", "starforge"], True),
        ("-m", ["python", "-mstarforge"], True),
        ("-m", ["python", "-m", "starforge.cli"], False),
        ("-m", ["python", "-m", "ipykernel_launcher", "-f", "k.json"], False),
        ("-c", ["python", "-c", "import starforge"], False),
        ("/home/u/analysis.py", ["python", "/home/u/analysis.py", "starforge"], False),
        ("/venv/bin/pytest", ["python", "/venv/bin/pytest", "-m", "starforge"], False),
    ],
)
def test_only_the_starforge_command_sets_handlers_on_import(argv0, orig, expected, monkeypatch):
    from starforge.runtime.stop import launched_as_command

    monkeypatch.setattr(sys, "argv", [argv0])
    monkeypatch.setattr(sys, "orig_argv", orig)
    assert launched_as_command() is expected


def test_a_program_importing_starforge_keeps_its_signal_handlers():
    # compared with the handlers the child starts with: a shell that starts a job in the
    # background hands it SIGINT ignored, and Python then keeps that instead of its own handler
    script = ("import signal\n"
              "before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)\n"
              "import starforge\n"
              "print(signal.getsignal(signal.SIGINT) is before[0],"
              " signal.getsignal(signal.SIGTERM) is before[1])\n")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=30)
    assert res.stdout.split() == ["True", "True"], res.stderr


@pytest.mark.parametrize("signame, code, word", [("SIGINT", 130, "interrupted"), ("SIGTERM", 143, "terminated")])
def test_a_signal_while_the_package_loads_in_the_command_is_one_line(signame, code, word, tmp_path):
    """A script named as the console script: ``import starforge`` alone (before the CLI, before
    ``__main__``) has set the handlers, so a signal right after it ends in the one line."""
    script = tmp_path / "starforge"
    script.write_text(f"import os, signal, time\nimport starforge\nos.kill(os.getpid(), signal.{signame})\n"
                      "time.sleep(30)\n")
    res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=30)
    assert res.returncode == code
    assert res.stderr.splitlines() == [f"{word}; no output was changed"]


def test_a_finalizer_failing_while_the_command_stops_says_nothing(monkeypatch):
    """An object a signal left half-built fails in its ``__del__`` while the command unwinds
    (llvmlite's ObjectRef): not reported once the command is stopping; reported otherwise."""
    from starforge.io import note_interrupt
    from starforge.runtime.process import command

    class HalfBuilt:
        def __del__(self):
            raise AttributeError("'ValueRef' object has no attribute '_as_parameter_'")

    reported = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: reported.append(u.exc_type))
    with command():
        HalfBuilt()
        assert reported == [AttributeError]  # an ordinary run: Python's report
        note_interrupt()
        HalfBuilt()
        assert reported == [AttributeError]


def test_a_signal_before_the_command_starts_ends_its_early_helpers(tmp_path):
    """A helper registered before the CLI loads (as the export's STEP worker is) ends with the
    early handler's one line: no process is left in the command's session."""
    script = tmp_path / "starforge"
    script.write_text(
        "import os, signal, subprocess, sys, time\nimport starforge\nfrom starforge.runtime import procs\n"
        "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
        "procs.adopt(child.pid)\nos.kill(os.getpid(), signal.SIGTERM)\ntime.sleep(30)\n"
    )
    proc = subprocess.Popen([sys.executable, str(script)], stderr=subprocess.PIPE, text=True, start_new_session=True)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 143 and err.splitlines() == ["terminated; no output was changed"]
    deadline = time.monotonic() + 5
    while left_in_session(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert left_in_session(proc.pid) == []
