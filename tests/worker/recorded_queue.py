"""The queue's recorder and the test job's shape, shared by ``conftest.py`` and the tests."""

from __future__ import annotations

from dataclasses import dataclass, field

IMAGES = 8
CHUNK_SIZE = 4
# Images rendered through a rig at half the true scale: no posture of the model explains them,
# so they fit over the error threshold and are the ones re-analysis must pick.
MISFIT = (2, 5)


@dataclass
class Recorder:
    """Stands in for the queue: the messages the orchestration sent, in order."""

    sent: list[tuple[str, tuple[int, ...]]] = field(default_factory=list)

    def __call__(self, name: str, *args: int) -> None:
        self.sent.append((name, args))

    def take(self) -> list[tuple[str, tuple[int, ...]]]:
        """The messages sent since the last take, emptied as a worker would consume them."""
        taken, self.sent = self.sent, []
        return taken
