"""A particle set that slid off the map finds its way back (``correlation.recover_search_m``).

The window search moves each particle at most its window (+-0.2 m indoors) per scan; a set that
got further off (along a corridor whose walls fit at any offset, at a revisit) keeps fitting a
local optimum badly while the right pose, 0.3-0.7 m away, would fit well. After each correction
the best particle is searched again in a wide window; when that finds a much better fit on
consecutive corrections with shifts that agree, the predicted set is shifted by it and corrected
again. docs/architecture.md, "A set that slid off the map".
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .config import CorrelationConfig
from .correlation import correlate, usable_points, window_reach_m, window_search
from .geometry import compose, relative_pose
from .likelihood import LikelihoodField


class Recovery:
    """``correlation.recover_search_m``: brings back a particle set that slid off the map beyond
    the reach of the window search (a corridor's length, a loop's revisit), one shift of the
    whole set once a wide search of the best particle agrees with itself over consecutive
    corrections (see :class:`~.config.CorrelationConfig`). Holds the recent wide-search
    shifts; :attr:`fired` counts the shifts applied."""

    #: the wide search's fit must be at least this fraction of the local one (scores are < 0)
    RATIO = 0.5
    #: consecutive shifts agree when each of (x m, y m, yaw rad) spans at most this
    AGREE = 0.1

    def __init__(self) -> None:
        self._shifts: list[tuple[int, np.ndarray]] = []
        self.fired = 0
        self.last: dict | None = None

    def correct(
        self,
        n: int,
        predicted: np.ndarray,
        corrected: np.ndarray,
        scores: np.ndarray,
        points: np.ndarray,
        field: LikelihoodField,
        cfg: CorrelationConfig,
        match: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The corrected set and scores of correction ``n`` (its ``predicted`` set, what
        :func:`correlate` made of it), or those of the predicted set shifted and corrected again
        when the wide searches of this and the previous ``recover_corrections - 1`` corrections
        agree."""
        b = int(np.argmax(scores))
        best = float(scores[b])
        if best < -cfg.recover_min_gain:
            half = min(cfg.recover_search_m, window_reach_m(field, cfg.step_xy_m))
            wide = dataclasses.replace(cfg, search_x_m=half, search_y_m=half, search_yaw_rad=cfg.recover_search_yaw_rad)
            # where the wide window's best cell is the pose itself, refining it finds the local
            # match again (no gain): so 99 % of the wide searches on intel_2726 end here
            matched = usable_points(points, cfg, match)[1][:: cfg.beam_stride]
            cell = window_search(corrected[b : b + 1], matched, field, wide)[0][0] if len(matched) else corrected[b]
            if np.abs(relative_pose(corrected[b], cell)).max() > 1e-9:
                pose, score = correlate(corrected[b : b + 1], points, field, wide, match)
                if score[0] >= self.RATIO * best and score[0] >= best + cfg.recover_min_gain:
                    self._shifts.append((n, relative_pose(corrected[b], pose[0])))
        self._shifts = [(k, d) for k, d in self._shifts if k > n - cfg.recover_corrections]
        if len(self._shifts) < cfg.recover_corrections:
            return corrected, scores
        shifts = np.array([d for _, d in self._shifts])
        if np.ptp(shifts, axis=0).max() > self.AGREE:
            return corrected, scores
        self._shifts = []
        moved, moved_scores = correlate(compose(predicted, shifts[-1]), points, field, cfg, match)
        if moved_scores.max() <= best:
            return corrected, scores
        self.fired += 1
        self.last = {
            "correction": n,
            "shift": [round(float(v), 3) for v in shifts[-1]],
            "score_before": round(best, 1),
            "score_after": round(float(moved_scores.max()), 1),
        }
        return moved, moved_scores
