"""Columns of naocal's text tables, shared by the NAO's and the arm's `offsets` verbs (kinds/nao/offsets.py,
kinds/arm/offsets.py): a number right-aligned ('-' when missing), a value in the unit people read."""

from __future__ import annotations


def number_column(value, width=10, digits=4) -> str:
    return f"{'-':>{width}}" if value is None else f"{value:>{width}.{digits}f}"


def shown_value(value, unit):
    """An SI value in the unit tables show it in (solver.effect.shown: rad as deg, m as mm); None stays None."""
    from naocal.solver.effect import shown

    return None if value is None else shown(value, unit)[0]
