"""What a command's step computed, wrote and reports: :class:`Step`, the one return type of every ``run_*``."""

from dataclasses import dataclass
from pathlib import Path
from typing import Generic, TypeVar

Result = TypeVar("Result")


@dataclass(frozen=True)
class Step(Generic[Result]):
    """What a step computed (``result``) and wrote (``files``), and its text ``report``."""

    files: tuple[Path, ...]
    report: str
    result: Result
