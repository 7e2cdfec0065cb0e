"""Errors that reach the user as one clear line: where (file, line, element, road) and what."""

from __future__ import annotations


class MapkitError(Exception):
    """Base error; ``exit_code`` is what the CLI exits with (1: a stage failed, 2: unreadable input)."""

    exit_code = 1

    def __init__(
        self,
        message: str,
        *,
        file: str | None = None,
        line: int | None = None,
        element: str | None = None,
        road: str | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.file = file
        self.line = line
        self.element = element
        self.road = road

    def __str__(self) -> str:
        where = ""
        if self.file:
            where = f"{self.file}:{self.line}: " if self.line else f"{self.file}: "
        elif self.line:
            where = f"line {self.line}: "
        parts = []
        if self.road is not None:
            parts.append(f"road {self.road}")
        if self.element:
            parts.append(f"<{self.element}>")
        context = (" ".join(parts) + ": ") if parts else ""
        return f"{where}{context}{self.message}"


class InputError(MapkitError):
    """The input cannot be read or makes no sense (exit code 2)."""

    exit_code = 2


class StageError(MapkitError):
    """A pipeline stage failed on otherwise readable input (exit code 1)."""

    exit_code = 1
