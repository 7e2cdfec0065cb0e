"""One finding of the validator: which rule, how bad, where (road, lane, s, line) and what."""

from __future__ import annotations

from dataclasses import asdict, dataclass

ERROR = "error"
WARNING = "warning"
INFO = "info"
SEVERITIES = (ERROR, WARNING, INFO)


@dataclass(frozen=True)
class Hit:
    """What a rule check yields: the place and the message; the runner adds rule id and severity."""

    message: str
    road: str | None = None
    lane: int | None = None
    s: float | None = None
    line: int | None = None


@dataclass(frozen=True)
class Finding:
    rule: str
    severity: str
    road: str | None
    lane: int | None
    s: float | None
    line: int | None
    message: str

    def to_dict(self) -> dict:
        data = asdict(self)
        if data["s"] is not None:
            data["s"] = round(float(data["s"]), 3)
        return data

    def __str__(self) -> str:
        where = []
        if self.line is not None:
            where.append(f"line {self.line}")
        if self.road is not None:
            where.append(f"road {self.road}")
        if self.lane is not None:
            where.append(f"lane {self.lane}")
        if self.s is not None:
            where.append(f"s={self.s:.2f}")
        place = (", ".join(where) + ": ") if where else ""
        return f"{self.severity:<7} {self.rule:<32} {place}{self.message}"
