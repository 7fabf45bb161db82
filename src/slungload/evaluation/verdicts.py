"""The pre-flight check's verdicts as a run keeps them, and the warning they give: json only
(no torch), so the onboard path (`slungload fly`) reads what an export carried.

``VERDICTS_FILE`` in a run (or ensemble) folder maps a horizon N to the verdict of ``slungload
check`` there (``preflight.record_verdict`` writes it); ``export --for-mpc`` copies it into the
sidecar (key ``preflight``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

VERDICTS_FILE = "preflight.json"
# "may pay": necessary, not sufficient (docs/BENCHMARKS.md, "The check before flying": where
# the MPC itself limits the flight a better response buys nothing); "does not pay" held in all
# but three cases flown (docs/control.md).
PAYS, NOT = "may pay", "does not pay"


def verdicts_path(run: str | Path) -> Path:
    """Where a run folder, ensemble folder or ``.ckpt``'s folder keeps its verdicts."""
    run = Path(run).expanduser()
    return (run if run.is_dir() else run.parent) / VERDICTS_FILE


def read_verdicts(run: str | Path) -> dict[str, Any]:
    """The run's verdicts by horizon (as strings); {} where there are none or the file cannot
    be read."""
    path = verdicts_path(run)
    try:
        found = json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError):
        return {}
    return found if isinstance(found, dict) else {}


def note(
    verdicts: Mapping[str, Any],
    what: str,
    horizon: int,
    *,
    paired: bool = False,
    trust_window: int = 0,
) -> str | None:
    """A warning for an MPC over ``what`` at ``horizon`` where ``verdicts`` (``read_verdicts``'
    shape) say it does not pay there; None where it may pay or was not checked there.
    ``paired``: the MPC prices its plans with the physics model too (``--with-physics``), with
    ``trust_window`` (``--trust-window``) physics alone while the network predicts worse."""
    found = verdicts.get(str(horizon))
    if not isinstance(found, dict) or found.get("verdict") != NOT:
        return None
    try:
        value, low, high = found["ratio"]
        why = (
            found.get("reason")
            or found.get("why")
            or (
                f"its response score is {value:.2f} [{low:.2f}, {high:.2f}] x physics's (it may "
                f"pay where the interval lies below {found['pays_below']:g})"
            )
        )
    except (KeyError, TypeError, ValueError):
        why = "see its check.md"
    said = (f"the pre-flight check of {what} (on {found.get('data', '?')}) says it will not "
            f"beat the physics model in an MPC at N = {horizon}: {why}")  # fmt: skip
    if paired and trust_window:
        return (
            f"{said}; the physics model prices its plans too, and alone while the network "
            f"predicts the last {min(trust_window, horizon)} steps flown worse (--with-physics)"
        )
    if paired:
        return (f"{said}; the physics model prices its plans too (--with-physics), but with "
                "--trust-window 0 it cannot veto a network that is wrong everywhere "
                "(docs/control.md)")  # fmt: skip
    return (f"{said}; flying it anyway (--with-physics lets the physics model veto the plans "
            "only it believes in, and price them alone while the network predicts the steps "
            "just flown worse; docs/control.md)")  # fmt: skip


def verdict_note(
    run: str | Path, horizon: int, *, paired: bool = False, trust_window: int = 0
) -> str | None:
    """``note`` from the run's own ``VERDICTS_FILE``."""
    return note(read_verdicts(run), str(run), horizon, paired=paired, trust_window=trust_window)
