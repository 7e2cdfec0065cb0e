"""Warnings collected while reading: what, where (line, road, element)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Diagnostic:
    message: str
    line: int | None = None
    road: str | None = None
    element: str | None = None

    def __str__(self) -> str:
        where = f"line {self.line}: " if self.line else ""
        road = f"road {self.road}: " if self.road is not None else ""
        element = f"<{self.element}>: " if self.element else ""
        return f"{where}{road}{element}{self.message}"

    def as_dict(self) -> dict:
        return {"message": self.message, "line": self.line, "road": self.road, "element": self.element}
