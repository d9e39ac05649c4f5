"""Selecting the observations of one frame (scan) in an observation file."""

from __future__ import annotations

from ...errors import ParameterError
from .extract import Observations


def frame_rows(obs: Observations, sequence: str | None = None, frame_id: str | None = None) -> list[int]:
    """Rows of one frame. Default frame: the one with the most observations (first in file order on ties)."""
    frames: dict[tuple[str, str], list[int]] = {}
    for i, key in enumerate(zip(obs.sequence, obs.frame_id)):
        frames.setdefault(key, []).append(i)
    if not frames:
        raise ParameterError("the observation file is empty: nothing to show")
    if frame_id is None:
        cands = [k for k in frames if sequence is None or k[0] == sequence]
        if not cands:
            raise ParameterError(f"no frame of sequence {sequence!r} in the file")
        key = max(cands, key=lambda k: len(frames[k]))
        return frames[key]
    cands = [k for k in frames if k[1] == frame_id and (sequence is None or k[0] == sequence)]
    if not cands:
        known = ", ".join(sorted({f for _, f in frames})[:8])
        raise ParameterError(
            f"frame {frame_id!r} has no observation in the file (frames: {known}{', ...' if len(frames) > 8 else ''})"
        )
    if len(cands) > 1:
        raise ParameterError(
            f"frame {frame_id!r} exists in several sequences ({', '.join(k[0] for k in cands)}); give `sequence`",
            "sequence",
        )
    return frames[cands[0]]
