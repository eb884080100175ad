"""Error components along Newton iterations, like the [JSC20] figures (eta_disc, eta_lin, eta_alg vs k).

* :func:`newton_history` -- :func:`.components.estimate_components` of given iterates;
* :class:`ComponentsHistory` -- the same as a callback of a Newton loop;
* :func:`newton_iterates` -- plain semismooth Newton yielding its iterates (the production loop's
  callback receives only an ``IterationRecord``);
* :func:`plot_components_history` -- the figure.
"""
from __future__ import annotations

from typing import List, Optional, Sequence


from .components import estimate_components
from .view import expect_repeated_evaluations
from .options import EstimatorOptions

__all__ = ["newton_history", "ComponentsHistory", "plot_components_history"]


def newton_history(disc, iterates, *, errors: bool = True, options: Optional[EstimatorOptions] = None) -> List[dict]:
    """Components per iterate.

    Parameters
    ----------
    disc : FEMDiscretization
    iterates : iterable of (x, y) or (x, y, r_alg)
        the iterates X^k (k = 0, 1, ...) in order.
    errors : bool
        add ``err_energy`` and ``i_eff_total`` when the exact solution is known.
    options : EstimatorOptions, optional
        passed to :func:`.components.estimate_components`.

    Returns
    -------
    list of dict
        one row per iterate: ``k`` and :meth:`.components.Components.summary`.
    """
    rows = []
    expect_repeated_evaluations(disc)
    for k, it in enumerate(iterates):
        xk, yk = it[0], it[1]
        r = it[2] if len(it) > 2 else None
        comp = estimate_components(disc, xk, yk, r_alg=r, errors=errors, options=options)
        rows.append({"k": k, **comp.summary()})
    return rows


class ComponentsHistory:
    """Callback collecting :func:`.components.estimate_components` rows along a Newton loop.

    ``hist = ComponentsHistory(disc, every=1)``; call ``hist(k, x, y)`` (or ``hist(k, x, y,
    r_alg=...)``) after every iterate; ``hist.rows`` is the list of
    ``{"k": k, **Components.summary()}``; ``hist.plot(png)`` draws them.
    """

    def __init__(self, disc, every: int = 1, errors: bool = True, options: Optional[EstimatorOptions] = None):
        self.disc, self.every, self.errors, self.options = disc, max(int(every), 1), errors, options
        self.rows: List[dict] = []
        expect_repeated_evaluations(disc)

    def __call__(self, k: int, x, y, r_alg=None, sigma_alg=None):
        if k % self.every:
            return None
        comp = estimate_components(self.disc, x, y, r_alg=r_alg, sigma_alg=sigma_alg, errors=self.errors,
                                   options=self.options)
        self.rows.append({"k": k, **comp.summary()})
        return comp

    def plot(self, out_png) -> None:
        plot_components_history(self.rows, out_png)


def plot_components_history(rows: Sequence[dict], out_png) -> None:
    """eta_disc, eta_lin, eta_alg (and the error, if present) vs iteration k, log scale (matplotlib Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ks = [r["k"] for r in rows]
    fig, ax = plt.subplots(figsize=(6, 4))
    floor = 1e-16
    for key, style, label in [("eta_total", "k-", r"$\eta$"), ("eta_disc", "b-o", r"$\eta_{disc}$"),
                              ("eta_lin", "r-s", r"$\eta_{lin}$"), ("eta_alg", "g-^", r"$\eta_{alg}$"),
                              ("err_energy", "k--", r"$|||u-u_h|||$")]:
        if all(key in r for r in rows):
            ax.semilogy(ks, [max(r[key], floor) for r in rows], style, ms=4, label=label)
    ax.set_xlabel("Newton iteration k")
    ax.set_ylabel("estimators")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_png, dpi=120)
    plt.close(fig)
