"""The process supervisor: output forwarding, death detection, ordered shutdown (no ROS).
Waits are on events (a line of output, a process's exit through its pidfd), not on time."""
import io
import os
import select
import signal
import sys
import threading
import time

import pytest

from lightstage_bringup.supervisor import ExitReport, ProcessSpec, Supervisor
from lightstage_graph.exits import describe_exit

from helpers.bringup import pid_alive

pytestmark = pytest.mark.process

PY = sys.executable


def py(code: str) -> list[str]:
    return [PY, '-c', code]


# a child that says it is ready, then waits for a signal; optional signal handling set up
# before "ready"
def sleeper(setup: str = '') -> list[str]:
    return py('import signal, sys\n' + setup + '\nprint("ready", flush=True)\nwhile True: signal.pause()')


class Lines(io.StringIO):
    """A stream the supervisor forwards to, which wakes `wait_for` on each write."""

    def __init__(self):
        super().__init__()
        self._written = threading.Condition()

    def write(self, text: str) -> int:
        with self._written:
            n = super().write(text)
            self._written.notify_all()
        return n

    def wait_for(self, text: str, timeout_s: float = 30.0) -> None:
        with self._written:
            if not self._written.wait_for(lambda: text in self.getvalue(), timeout_s):
                raise AssertionError(f'{text!r} not seen; output so far:\n{self.getvalue()}')


def wait_for_line(stream: Lines, text: str) -> None:
    stream.wait_for(text)


def wait_for_pid_exit(pid: int, timeout_s: float = 30.0) -> bool:
    """True once process ``pid`` (any process, not only a child) has exited: its pidfd becomes
    readable then. False if it is still running after ``timeout_s``."""
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return True
    try:
        readable, _, _ = select.select([fd], [], [], timeout_s)
        return bool(readable)
    finally:
        os.close(fd)


def test_output_is_forwarded_line_by_line_with_the_name_and_logged(tmp_path):
    out, err = io.StringIO(), io.StringIO()
    with Supervisor(stdout=out, stderr=err, log_dir=tmp_path) as sup:
        sup.start(ProcessSpec('talker', py(
            'import sys; print("one"); print("two"); print("oops", file=sys.stderr)')))
        assert sup.wait_for_exit(timeout_s=10).name == 'talker'
        reports = sup.shutdown()
    assert out.getvalue().splitlines() == ['[talker] one', '[talker] two']
    assert err.getvalue().splitlines() == ['[talker] oops']
    # both streams go to one file; their relative order is up to the scheduler
    logged = (tmp_path / 'talker.log').read_text().splitlines()
    assert sorted(logged) == ['one', 'oops', 'two'] and logged.index('one') < logged.index('two')
    (r,) = reports
    assert r.returncode == 0 and r.signal_sent is None and r.clean
    assert r.expected is False  # exited by itself, nobody asked it to stop


def test_a_dying_child_is_reported_with_its_exit_code(tmp_path):
    out = Lines()
    crash = tmp_path / 'crash_now'
    os.mkfifo(crash)
    held_open = os.open(crash, os.O_RDWR)  # the crasher's read of the FIFO ends when this closes
    with Supervisor(stdout=out, stderr=io.StringIO()) as sup:
        sup.start(ProcessSpec('steady', sleeper()))
        # dies when told, while the supervisor watches the other one
        sup.start(ProcessSpec('crasher', py(
            f'import sys\nfifo = open({str(crash)!r})\nprint("ready", flush=True)\nfifo.read()\n'
            'sys.exit(3)')))
        # a SIGINT that lands while the child's interpreter is still starting can be lost
        # (seen once under load): only stop it once it runs its code
        wait_for_line(out, '[steady] ready')
        wait_for_line(out, '[crasher] ready')
        os.close(held_open)
        dead = sup.wait_for_exit(timeout_s=60)
        assert dead is not None and dead.name == 'crasher' and dead.returncode == 3
        assert sup['steady'].returncode is None
        reports = {r.name: r for r in sup.shutdown()}
    assert reports['crasher'].returncode == 3 and not reports['crasher'].expected
    assert reports['steady'].signal_sent == 'SIGINT' and reports['steady'].clean
    assert 'exit code 3' in str(reports['crasher'])


def test_shutdown_escalates_sigint_sigterm_sigkill():
    out = Lines()
    # grace periods long enough for a Python child to unwind on a loaded 2-core machine
    # (0.5 s was missed once with two CPU-bound benchmark workers running)
    sup = Supervisor(stdout=out, stderr=io.StringIO(), sigint_timeout_s=2.0, sigterm_timeout_s=2.0)
    sup.start(ProcessSpec('polite', sleeper()))
    sup.start(ProcessSpec('deaf_to_int', sleeper('signal.signal(signal.SIGINT, signal.SIG_IGN)')))
    sup.start(ProcessSpec('stubborn', sleeper(
        'signal.signal(signal.SIGINT, signal.SIG_IGN); signal.signal(signal.SIGTERM, signal.SIG_IGN)')))
    for name in ('polite', 'deaf_to_int', 'stubborn'):
        wait_for_line(out, f'[{name}] ready')
    pids = [p.pid for p in sup.processes]
    t0 = time.monotonic()
    reports = {r.name: r for r in sup.shutdown()}
    elapsed = time.monotonic() - t0
    assert reports['polite'].signal_sent == 'SIGINT' and reports['polite'].clean
    assert reports['deaf_to_int'].signal_sent == 'SIGTERM'
    assert reports['deaf_to_int'].returncode == -signal.SIGTERM and reports['deaf_to_int'].clean
    assert reports['stubborn'].signal_sent == 'SIGKILL'
    assert reports['stubborn'].returncode == -signal.SIGKILL and not reports['stubborn'].clean
    assert elapsed >= 4.0  # waited out both grace periods before the harder signal
    assert not any(pid_alive(pid) for pid in pids)


def test_children_stop_on_sigint_even_when_the_supervisor_ignores_it():
    # A supervisor started from a background job ignores SIGINT; its children must not
    # inherit that, or the SIGINT of a clean stop goes unheard until SIGTERM.
    import subprocess
    code = (
        'import io, signal, sys\n'
        'from lightstage_bringup.supervisor import ProcessSpec, Supervisor\n'
        'signal.signal(signal.SIGINT, signal.SIG_IGN)\n'
        'sup = Supervisor(stdout=sys.stdout, stderr=io.StringIO(), sigint_timeout_s=20)\n'
        'sup.start(ProcessSpec("child", [sys.executable, "-c", "import signal\\n"\n'
        '    "print(signal.getsignal(signal.SIGINT) is signal.default_int_handler, flush=True)\\n"\n'
        '    "while True: signal.pause()"]))\n'
        'print(sys.stdin.readline().strip(), flush=True)\n'
        'r = sup.shutdown()[0]\n'
        'print("stopped by", r.signal_sent, r.returncode, flush=True)\n')
    boss = subprocess.Popen([PY, '-c', code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True)
    try:
        assert boss.stdout.readline().strip() == '[child] True'  # Python's own SIGINT handler
        boss.stdin.write('go\n')
        boss.stdin.flush()
        assert boss.stdout.readline().strip() == 'go'
        # stopped by the SIGINT (KeyboardInterrupt: exit status 1 or -SIGINT), not SIGTERM
        assert boss.stdout.readline().split()[:3] == ['stopped', 'by', 'SIGINT']
        assert boss.wait(timeout=30) == 0
    finally:
        boss.kill()
        boss.stdout.close()
        boss.stdin.close()


def test_grandchildren_are_stopped_with_their_parent():
    out = Lines()
    with Supervisor(stdout=out, stderr=io.StringIO(), sigint_timeout_s=2) as sup:
        sup.start(ProcessSpec('parent', py(
            'import signal, subprocess, sys\n'
            'c = subprocess.Popen([sys.executable, "-c", "import signal\\nwhile True: signal.pause()"])\n'
            'print("grandchild", c.pid, flush=True)\n'
            'while True: signal.pause()')))
        wait_for_line(out, '[parent] grandchild ')
        grandchild = int(out.getvalue().split('grandchild ')[1].split()[0])
        assert pid_alive(grandchild)
    assert wait_for_pid_exit(grandchild)


def test_child_gets_sigterm_when_the_supervisor_process_dies(tmp_path):
    # A supervisor process that starts a child and is then SIGKILLed: no orphan survives.
    import subprocess
    code = (
        'import io, signal, sys\n'
        'from lightstage_bringup.supervisor import ProcessSpec, Supervisor\n'
        'sup = Supervisor()\n'
        'p = sup.start(ProcessSpec("orphan", [sys.executable, "-c",\n'
        '                                     "import signal\\nwhile True: signal.pause()"]))\n'
        'print(p.pid, flush=True)\n'
        'while True: signal.pause()\n')
    boss = subprocess.Popen([PY, '-c', code], stdout=subprocess.PIPE, text=True)
    try:
        child_pid = int(boss.stdout.readline())
        assert pid_alive(child_pid)
        boss.kill()
        boss.wait(timeout=30)
        assert wait_for_pid_exit(child_pid)
    finally:
        boss.kill()
        boss.stdout.close()


def test_bad_specs_are_rejected_clearly():
    with pytest.raises(ValueError, match='argv is empty'):
        ProcessSpec('x', [])
    with pytest.raises(ValueError, match='without spaces'):
        ProcessSpec('two words', ['true'])
    with Supervisor(stdout=io.StringIO(), stderr=io.StringIO()) as sup:
        sup.start(ProcessSpec('same', ['true']))
        with pytest.raises(ValueError, match='already started'):
            sup.start(ProcessSpec('same', ['true']))


def test_describe_exit():
    assert describe_exit(None) == 'still running'
    assert describe_exit(0) == 'exit code 0'
    assert describe_exit(-9) == 'killed by SIGKILL'
    assert ExitReport('n', 1, 130, 'SIGINT').clean
    assert not ExitReport('n', 1, 1, 'SIGINT').clean
