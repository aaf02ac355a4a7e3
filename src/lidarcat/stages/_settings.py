"""The optional survey.toml tables that plan a stage (``[mapping]``, ``[products]``)."""

from __future__ import annotations

from typing import Any

__all__ = ["optional_table"]


def optional_table(survey: Any, table: str, kinds: dict[str, Any], defaults: dict[str, Any]
                   ) -> tuple[dict[str, Any], Any]:
    """``[table]`` of *survey*'s survey.toml read key by key with its defaults.

    Returns ``({}, t)`` when the table is absent, else the values (each checked
    against its type in *kinds*, a wrong type is a :class:`~lidarcat.errors.SurveyError`
    naming file, line and key) and the parsed file ``t``, whose ``t.err(table, key, msg)``
    builds further located errors.
    """
    from ..survey.folder import _Toml

    t = _Toml(survey.toml_path)
    if table not in t.data:
        return {}, t
    return {key: t.get(table, key, kind, defaults[key]) for key, kind in kinds.items()}, t
