"""Seed lists as the benchmarks take them on the command line."""

from __future__ import annotations

__all__ = ["seed_list"]


def seed_list(text: str) -> list[int]:
    """'100-104', '100,101,107' or both, '141-146,151'; ValueError naming a bad item."""
    seeds = []
    for item in text.split(","):
        lo, _, hi = item.strip().partition("-")
        try:
            first, last = int(lo), int(hi or lo)
        except ValueError:
            raise ValueError(f"seeds: {item!r} is not a seed or a range like 100-104") from None
        if last < first:
            raise ValueError(f"seeds: {item!r}: the last seed is before the first")
        seeds += range(first, last + 1)
    return seeds
