"""Stage ``camera``: interior orientation of every pixel measurement (eq. 01-07).

Writes ``camera/corrected.csv`` (corrected photo coordinates, mm) and, where
the survey also gives corrected coordinates (the thesis prints them), the
largest difference from them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .context import StageContext as Context

__all__ = ["run"]


def run(ctx: Context, tmp: Path) -> dict:
    """Interior orientation of every pixel measurement (eq. 01-07) -> camera/corrected.csv."""
    from ..survey.folder import correct_measurements

    survey = ctx["survey"]
    corrected = correct_measurements(survey)
    corrected.write_csv(tmp / "corrected.csv")
    result = dict(corrected.to_dict())
    # where the survey also gives corrected coordinates (the thesis prints them), compare
    ip = survey.image_points
    given = {(str(a), str(b)): xy for a, b, xy in zip(ip.photo, ip.point, ip.xy_mm)
             if np.isfinite(xy).all()}
    diffs = [np.abs(xy - given[(str(a), str(b))])
             for a, b, xy in zip(corrected.photo, corrected.point, corrected.xy_mm)
             if (str(a), str(b)) in given]
    if diffs:
        d = np.array(diffs)
        result["n_compared_with_file"] = len(d)
        result["max_abs_diff_file_mm"] = float(d.max())
    ctx.progress(1, 1)
    return result

