"""Plots of a bundle run (:func:`upscale.experiments.scenes.bundle_pull.dynamic_tension`'s
result dict): the bundle's and each tube's stress-strain curves beside LAMMPS's, and every
tube's damage on its unrolled surface."""
from __future__ import annotations

import numpy as np

from upscale.analysis.plots import save_figure

__all__ = ["plot_curves", "plot_damage_maps"]


def plot_curves(res, path, lammps=None, title=""):
    """Bundle and per-tube stress-strain curves, ours (solid) and LAMMPS's (dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, what in zip(axs, ("bundle", "tubes")):
        for src, r, ls in (("engine", res, "-"), ("LAMMPS", lammps, "--")):
            if r is None:
                continue
            e = 100 * np.asarray(r["curve"]["strain"])
            if what == "bundle":
                ax.plot(e, r["curve"]["stress_GPa"], ls, lw=1.5, label=f"bundle, {src}")
            else:
                P = r["curve"].get("stress_per_tube_GPa")
                if P is None:
                    continue
                P = np.asarray(P)
                for k in range(P.shape[1]):
                    ax.plot(e[:len(P)], P[:, k], ls, lw=1.0 if k else 1.8, color=f"C{k}",
                            label=f"tube {k + 1}{' (centre)' if k == 0 else ''}, {src}")
        ax.set_xlabel("axial strain (%)")
        ax.set_ylabel("stress (GPa), wall t = 3.4 Å")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, ncol=2)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path, dpi=130)


def plot_damage_maps(res, path, title=""):
    """The damage of every tube on its unrolled surface, side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = res["damage"]
    fig, axs = plt.subplots(1, len(d), figsize=(2.3 * len(d), 4.6), sharey=True)
    axs = np.atleast_1d(axs)
    for ax, t in zip(axs, d):
        mu = np.asarray(t["mu"])
        o = np.argsort(mu)
        sc = ax.scatter(np.asarray(t["s"])[o], np.asarray(t["z"])[o], c=mu[o],
                        s=np.where(mu[o] > 0, 6.0, 1.5), cmap="inferno_r", vmin=0, vmax=1,
                        linewidths=0)
        ax.set_title(f"tube {t['tube']}: {t['model']}", fontsize=8)
        ax.set_xlabel("s = R θ (Å)", fontsize=7)
    axs[0].set_ylabel("z (Å)")
    fig.colorbar(sc, ax=list(axs), label="damage mu", shrink=0.8)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path, dpi=130)
