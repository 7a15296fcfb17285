"""How a process ended, in words (the supervisor's reports, the driver's simulator)."""
import signal


def describe_exit(returncode: int | None) -> str:
    """Human-readable exit status: 'exit code 3', 'killed by SIGKILL', 'still running'."""
    if returncode is None:
        return 'still running'
    if returncode < 0:
        try:
            return f'killed by {signal.Signals(-returncode).name}'
        except ValueError:
            return f'killed by signal {-returncode}'
    return f'exit code {returncode}'
