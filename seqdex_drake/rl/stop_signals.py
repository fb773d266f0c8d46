"""SIGINT and SIGTERM as a stop request, so that a training run saves its checkpoint before it exits.

Inside ``with StopSignals() as stop:`` the first SIGINT (Ctrl-C) or SIGTERM (``kill``, a scheduler's preemption)
only records itself (:attr:`StopSignals.received`); the code checks it between units of work
(:meth:`~seqdex_drake.rl.ppo.PPO.train`: between updates), saves and returns. A second signal raises
:class:`KeyboardInterrupt` at once, for a user who does not want to wait (atomic writes keep every saved file
whole). Leaving the block restores the previous handlers. A signal the process ignores (``SIG_IGN``, e.g. SIGINT in
a job a script started in the background) stays ignored. Outside the main thread, where Python cannot install
signal handlers, nothing is installed and the object is only a flag (:meth:`StopSignals.request`).
"""

import signal
import threading


class StopSignals:
    """A stop request set by SIGINT / SIGTERM while the ``with`` block runs.

    Args:
        signals: the signals that request a stop (default: SIGINT and SIGTERM).
    """

    def __init__(self, signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)):
        self.signals = tuple(signals)
        self.signum: int | None = None
        """The signal that requested the stop (its number), or None."""
        self._previous: dict[int, object] = {}

    @property
    def received(self) -> str | None:
        """The name of the signal that requested the stop (``"SIGTERM"``), or None."""
        return None if self.signum is None else signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """The shell's status for a process ended by the signal: 128 + its number (130 SIGINT, 143 SIGTERM)."""
        if self.signum is None:
            raise ValueError("no stop was requested")
        return 128 + self.signum

    def request(self, signum: int = signal.SIGTERM) -> None:
        """Requests the stop as the signal ``signum`` would (the first request counts)."""
        if self.signum is None:
            self.signum = int(signum)

    def _handle(self, signum: int, frame) -> None:
        if self.signum is not None:  # The second signal: stop now.
            raise KeyboardInterrupt
        self.signum = signum

    def __enter__(self) -> "StopSignals":
        if threading.current_thread() is threading.main_thread():
            for sig in self.signals:
                if signal.getsignal(sig) is not signal.SIG_IGN:
                    self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc_info) -> bool:
        for sig, handler in self._previous.items():  # None: a handler not installed from Python (the default).
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        self._previous = {}
        return False
