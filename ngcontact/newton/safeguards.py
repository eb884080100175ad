"""Safeguards of the Newton loop: cycling of Newton-min and stalling of Newton-FB, detected and remedied.

* **Cycling** (Newton-min): the active set {w g <= y} of iterate k equals the one of a Newton iterate
  1 <= j <= k - 2, differs from that of k - 1, and ||Phi|| has not halved since iterate j: with exact
  solves of a linear system the step from an active set is determined by it, so the iteration repeats
  itself from there on.  (The initial guess is not a Newton iterate; and a nonlinear system may come
  back to an active set while converging, which the residual test tells apart.)
  Remedies, in this order: solve the steps with a fresh factorization (an inexact PCG solve with a reused
  factorization can flip a row back and forth, :mod:`ngcontact.algebra.reuse`) -- in the inexact Krylov mode:
  solve them to the gmres mode's tolerance instead of the forcing term (the [CMAME20] rings, P1 on 19k
  triangles, Newton-FB inexact: step 15 cycled and stopped at ||Phi||/||F|| = 3.9) --, then continue with
  Newton-FB and its line search (globally convergent on the merit function).
* **Stalling** (Newton-FB): the Armijo line search fails (step < min_step).  Near degenerate rows
  (g = y = 0, e.g. the P2 vertices, whose dual-basis multiplier has a zero-mean partner) the FB direction
  can be a poor descent direction; the remedy continues with full Newton-min steps from the current iterate.

Each remedy is taken at most once per solve; trouble after it stops the loop with a named reason.
The remedies are logged: ``IterationRecord.remedy`` (index in :data:`REMEDIES`) and
``NewtonResult.remedies`` (one line each).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

__all__ = ["REMEDIES", "Safeguards"]

#: IterationRecord.remedy codes
REMEDIES = ("none", "fresh factorization", "switch to Newton-min", "switch to Newton-FB")


class Safeguards:
    """State of the cycling and stalling detection of one Newton solve."""

    def __init__(self, session=None):
        self.session = session  # the linear strategy's session (set once started)
        self.seen: dict = {}  # signature of an active set -> (last iteration that had it, its ||Phi|| / ||F||)
        self.prev: Optional[bytes] = None
        self.used: set = set()
        self.log: list = []

    @staticmethod
    def signature(active: np.ndarray) -> bytes:
        return np.packbits(active).tobytes()

    def cycling(self, k: int, active: np.ndarray, res: float) -> Optional[int]:
        """The earlier iteration j <= k - 2 with the same active set as k (and a different one at k - 1) and
        ||Phi|| not halved since, else None (module doc); ``res``: ||Phi(X^k)|| / ||F||."""
        sig = self.signature(active)
        j, res_j = self.seen.get(sig, (None, None))
        back = j is not None and j <= k - 2 and sig != self.prev and res > 0.5 * res_j
        self.seen[sig], self.prev = (k, res), sig
        return j if back else None

    def next_remedy(self, trouble: str) -> Optional[int]:
        """The remedy code for ``trouble`` ('cycling' or 'stall') not used yet, or None (none left)."""
        if trouble == "cycling":
            options = ([1] if getattr(self.session, "can_refresh", False) else []) + [3]
        else:
            options = [2]
        for code in options:
            if code not in self.used:
                self.used.add(code)
                if code == 1:
                    self.session.fresh()
                return code
        return None

    def note(self, k: int, code: int, why: str) -> None:
        label = getattr(self.session, "refresh_label", REMEDIES[code]) if code == 1 else REMEDIES[code]
        self.log.append(f"iteration {k}: {why}: {label}")
