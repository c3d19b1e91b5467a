"""Matplotlib plots: stress–strain overlays and damage maps on the unrolled tube surface.

Small PNGs (default 6.4 x 4 inches at 90 dpi) written atomically via :mod:`upscale.io`.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

__all__ = ["plot_stress_strain", "plot_damage_map", "save_figure"]


def save_figure(fig, path, dpi: int = 90, **savefig_kw) -> Path:
    """Write ``fig`` as a PNG to ``path`` atomically (:func:`upscale.io.atomic_write_bytes`:
    a killed run never leaves a truncated picture), close it, return the path."""
    from upscale.io import atomic_write_bytes  # noqa: PLC0415

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, **savefig_kw)
    import matplotlib.pyplot as plt  # noqa: PLC0415

    plt.close(fig)
    return atomic_write_bytes(path, buf.getvalue())


def _save(fig, path) -> Path:
    return save_figure(fig, path, dpi=90, bbox_inches="tight")


def plot_stress_strain(curves, path, title: str = "", mark_peak: bool = True) -> Path:
    """Overlay stress–strain curves.

    Parameters
    ----------
    curves : list of (label, strain, stress_GPa) or of result dicts
        A result dict needs ``curve.strain``, ``curve.stress_GPa`` and a ``label`` key (else
        its protocol and chirality are used).
    path : str or Path
        PNG file.
    """
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for c in curves:
        if isinstance(c, dict):
            label = c.get("label") or f"{c.get('protocol')} {c.get('structure', {}).get('chirality')}"
            e, s = c["curve"]["strain"], c["curve"]["stress_GPa"]
            peak = (c.get("strain_at_peak"), c.get("strength_GPa"))
        else:
            label, e, s = c
            peak = (None, None)
        (line,) = ax.plot(100 * np.asarray(e), s, lw=1.3, label=label)
        if mark_peak and peak[0] is not None:
            ax.plot(100 * peak[0], peak[1], "o", ms=4, color=line.get_color())
    ax.set_xlabel("axial strain (%)")
    ax.set_ylabel("stress (GPa), wall t = 3.4 Å")
    ax.axhline(0, color="0.7", lw=0.6)
    if title:
        ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)
    return _save(fig, path)


def plot_damage_map(s_n, z_n, mu_n, path, title: str = "", vacancy_sz=None, line=None,
                    radius: float | None = None) -> Path:
    """Damage index on the unrolled tube surface (arc s = R theta vs axial z).

    Parameters
    ----------
    s_n, z_n, mu_n : (N,) float
        Arc coordinate (Å), axial coordinate (Å), damage index in [0, 1].
    vacancy_sz : (2,) float, optional
        The vacancy centre (s, z), marked with a cross.
    line : dict, optional
        Result of :func:`upscale.analysis.damage.crack_line`, drawn through its centre.
    """
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    s, z, mu = (np.asarray(a, dtype=float) for a in (s_n, z_n, mu_n))
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    order = np.argsort(mu)  # damaged atoms on top
    size = np.where(mu[order] > 0, 14.0, 3.0)  # damaged atoms drawn larger
    sc = ax.scatter(z[order], s[order], c=mu[order], s=size, cmap="inferno_r", vmin=0, vmax=1,
                    linewidths=0)
    fig.colorbar(sc, ax=ax, label="damage index mu = 1 - R/T")
    if vacancy_sz is not None:
        ax.plot(vacancy_sz[1], vacancy_sz[0], "x", color="tab:blue", ms=9, mew=2,
                label="vacancy")
    if line is not None:
        half = max(line.get("extent_A", 10.0), 5.0)
        us, uz = line["direction_sz"]
        dz, ds = uz * half, us * half
        cz, cs = line["centre_z_A"], line["centre_s_A"]
        ax.plot([cz - dz, cz + dz], [cs - ds, cs + ds], "--", color="tab:green", lw=1.2,
                label=f"crack line, {line['angle_to_axis_deg']:.0f}° to axis")
    ax.set_xlabel("z (Å, tube axis)")
    ax.set_ylabel("s = R θ (Å, unrolled circumference)")
    if title:
        ax.set_title(title, fontsize=10)
    if vacancy_sz is not None or line is not None:
        ax.legend(fontsize=7, loc="upper right")
    return _save(fig, path)
