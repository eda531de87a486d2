"""What went wrong in one life of the service, in order.

The first failure is what ended the run (a receive error of a vanished controller); what
follows it is its consequence (the same link then fails to close, the last checkpoint
fails to write). Each step of a shutdown runs whatever failed before it, and the user sees
the first failure first, the follow-on errors after it, never a follow-on in its place.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

__all__ = ["Failures"]


class Failures:
    """The failures of one service, the first first (see the module docstring)."""

    def __init__(self) -> None:
        self._seen: list[tuple[str, BaseException]] = []

    def add(self, stage: str, error: BaseException) -> None:
        """Record ``error``, raised while ``stage`` (e.g. ``"closing the link"``)."""
        if not any(error is seen for _, seen in self._seen):
            self._seen.append((stage, error))

    def __bool__(self) -> bool:
        return bool(self._seen)

    def __len__(self) -> int:
        return len(self._seen)

    @property
    def first(self) -> BaseException | None:
        """The first failure, or None."""
        return self._seen[0][1] if self._seen else None

    @property
    def follow_ons(self) -> list[tuple[str, BaseException]]:
        """``(stage, error)`` of each failure after the first, in order."""
        return self._seen[1:]

    def run_all(self, steps: Iterable[tuple[str, Callable[[], object]]]) -> None:
        """Run every step, each even if one before it failed; a failure is recorded. The
        first failure of this service is raised once all have run; a later one is only
        recorded: the failure before it is already on its way to the caller."""
        had = bool(self._seen)
        for stage, step in steps:
            try:
                step()
            except Exception as exc:
                self.add(stage, exc)
        if not had and self._seen:
            raise self._seen[0][1]
