"""Inputs that belong together: radiance EXRs against the profile that is said to have made them.

Every EXR of ``camcal apply`` stores the content hash of its profile (``camcal:profile_sha256``), the profile's
camera (``profile_camera``) and the radiance scale (``radiance_scale``: absolute or relative). A ratio of two
EXRs made by different profiles, or of a relative and an absolute one, is not the ratio of the two scenes; a
band model built from one profile's c(λ) applied to EXRs of another is a wrong C. These checks refuse such
inputs in one line that names both sides. An EXR that holds no hash (written by another tool) is not checked:
its provenance is unknown, not wrong.
"""

from __future__ import annotations

from pathlib import Path

from camcal.errors import CamcalError


def _short(sha: str | None) -> str:
    return f"{sha[:12]}…" if sha else "unknown"


def _camera(meta: dict) -> str:
    cam = meta.get("profile_camera") or {}
    name = " ".join(str(v) for v in (cam.get("make"), cam.get("model")) if v)
    return f" ({name})" if name else ""


def check_made_by(meta: dict, path: str | Path, profile, profile_path: str | Path) -> None:
    """Refuse the EXR at ``path`` (header ``meta``) when its profile hash is not ``profile``'s."""
    made = meta.get("profile_sha256")
    want = getattr(profile, "content_sha256", None)
    if made and want and made != want:
        cam = profile.camera
        own = " ".join(str(v) for v in (cam.make, cam.model) if v)
        raise CamcalError(f"was made by the profile {_short(made)}{_camera(meta)}, not by --profile {profile_path} "
                          f"({_short(want)}{', ' + own if own else ''}): apply --profile to the photos again, or give "
                          "the profile that made the EXR", path)


def check_pair(meta_a: dict, path_a: str | Path, meta_b: dict, path_b: str | Path) -> None:
    """Refuse two EXRs of one ratio made by different profiles or on different radiance scales."""
    sa, sb = meta_a.get("radiance_scale"), meta_b.get("radiance_scale")
    if sa and sb and sa != sb:
        raise CamcalError(f"holds {sa} radiance but {Path(path_b).name} holds {sb} radiance: a ratio needs both "
                          "from one profile (apply the same profile to both photos)", path_a)
    ha, hb = meta_a.get("profile_sha256"), meta_b.get("profile_sha256")
    if ha and hb and ha != hb:
        raise CamcalError(f"was made by the profile {_short(ha)}{_camera(meta_a)} but {Path(path_b).name} by "
                          f"{_short(hb)}{_camera(meta_b)}: a ratio needs both from one profile", path_a)
