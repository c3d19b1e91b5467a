"""Analysis functions on synthetic data with known answers."""
import math

import numpy as np
import pytest

from upscale.analysis.damage import (bond_network, crack_line, damage_index, dump_damage,
                                     unroll)
from upscale.analysis.stress import (curve_metrics, stress_from_force, stress_from_pressure,
                                     wall_area)
from upscale.build import graphene, swcnt


def test_wall_area_and_unit_conversions():
    assert wall_area(2.0, 3.4) == pytest.approx(2 * math.pi * 2.0 * 3.4)
    assert wall_area(2.0, 3.4, ntubes=7) == pytest.approx(7 * 2 * math.pi * 2.0 * 3.4)
    # 1 eV/Å over 1 Å^2 = 160.2177 GPa
    A = wall_area(1.0 / (2 * math.pi * 3.4))
    assert stress_from_force(1.0, 1.0 / (2 * math.pi * 3.4)) == pytest.approx(160.21766208)
    # -pzz V / (A L): 1e4 bar of -pzz with V = A L gives 1 GPa
    R, L = 5.0, 20.0
    V = wall_area(R) * L
    assert stress_from_pressure(-1e4, V, L, R) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="radius"):
        wall_area(-1.0)


def test_curve_metrics_linear_then_drop():
    e = np.linspace(0, 0.2, 41)
    s = 1000.0 * e  # 1 TPa
    s[30:] = [s[29] * 0.5] * 11  # sudden failure after strain 0.145
    m = curve_metrics(e, s)
    assert m["youngs_modulus_TPa"] == pytest.approx(1.0)
    assert m["strength_GPa"] == pytest.approx(s[29])
    assert m["strain_at_peak"] == pytest.approx(e[29])
    assert m["failure_strain"] == pytest.approx(e[30])
    assert m["failed"] and not m["rise_after_plateau"]


def test_curve_metrics_small_dip_is_not_failure_and_plateau_rise_flagged():
    e = np.linspace(0, 0.4, 81)
    s = 800 * e
    s[40] = s[39] * 0.97  # a 3 % dip is no failure
    m = curve_metrics(e, s)
    assert not m["failed"] and m["strength_GPa"] == pytest.approx(s[-1])
    # plateau from 0.2 to 0.3, then a rise (switching-function artefact)
    s2 = np.where(e < 0.2, 800 * e, 160.0)
    s2 = np.where(e > 0.3, 160.0 + 1500 * (e - 0.3), s2)
    m2 = curve_metrics(e, s2)
    assert m2["rise_after_plateau"]
    assert m2["strength_GPa"] == pytest.approx(160.0)
    assert m2["max_stress_before_failure_GPa"] > 200


def test_damage_index_hand_made_network():
    # a 4-atom chain 0-1-2-3 plus a branch 1-4; break bond 1-2 by moving 2, 3 away
    x = np.array([[0, 0, 0], [1.4, 0, 0], [2.8, 0, 0], [4.2, 0, 0], [1.4, 1.4, 0.0]])
    pairs = bond_network(x, 1.6)
    assert pairs.tolist() == [[0, 1], [1, 2], [1, 4], [2, 3]]
    y = x.copy()
    y[2:4, 0] += 1.0
    mu = damage_index(pairs, y, break_cutoff=2.1)
    # atom 1 had 3 bonds and lost 1; atom 2 had 2 and lost 1; others intact
    assert np.allclose(mu, [0, 1 / 3, 1 / 2, 0, 0])
    # an isolated atom (no reference bonds) has mu = 0
    assert damage_index(pairs, y, n_atoms=6)[5] == 0.0


def test_damage_index_periodic_minimum_image():
    t = swcnt(10, 10, 20.0)
    box = [1e6, 1e6, t.cell[2, 2]]
    pairs = bond_network(t.positions, 2.0, box)
    assert len(pairs) == 3 * len(t) // 2  # 3 bonds per atom across the boundary
    assert np.all(damage_index(pairs, t.positions, 2.1, box) == 0)
    # without the periodic box the bonds across z = 0 / L look broken after a stretch
    y = t.positions.copy()
    y[:, 2] *= 1.05
    box2 = [1e6, 1e6, 1.05 * t.cell[2, 2]]
    assert np.all(damage_index(pairs, y, 2.1, box2) == 0)


def test_unroll_and_crack_line_known_angle():
    R = 7.0
    rng = np.random.default_rng(1)
    for angle in (90.0, 60.0, 30.0):
        # points along a straight line on the (s, z) plane at `angle` to the z axis
        t = np.linspace(-15, 15, 60)
        a = math.radians(angle)
        s = t * math.sin(a) + rng.normal(0, 0.05, t.size)
        z = 50 + t * math.cos(a) + rng.normal(0, 0.05, t.size)
        # roll them up onto a tube around (20, 20) and unroll again
        th = s / R
        x = np.column_stack([20 + R * np.cos(th), 20 + R * np.sin(th), z])
        s2, z2 = unroll(x, (20.0, 20.0), radius=R)
        assert np.allclose(s2, s, atol=1e-9) and np.allclose(z2, z)
        line = crack_line(s2, z2)
        assert line["angle_to_axis_deg"] == pytest.approx(angle, abs=1.0)
        assert line["centre_z_A"] == pytest.approx(50.0, abs=0.1)
        assert line["straightness"] > 0.99
    # a tilted line with negative slope gives the same angle, direction keeps the sign
    line = crack_line(-np.linspace(-5, 5, 11), np.linspace(-5, 5, 11) * 0.0 + np.linspace(0, 10, 11))
    assert line["angle_to_axis_deg"] == pytest.approx(45.0)
    assert line["direction_sz"][0] < 0 < line["direction_sz"][1]
    with pytest.raises(ValueError, match="2 points"):
        crack_line([1.0], [2.0])


def test_dump_damage_reads_lammps_dump_with_mdanalysis(tmp_path):
    """A hand-written 2-frame LAMMPS dump of a graphene patch: frame 2 cuts one row."""
    g = graphene(3, 3)
    x = g.positions
    n = len(x)

    def frame(step, xx):
        lines = ["ITEM: TIMESTEP", str(step), "ITEM: NUMBER OF ATOMS", str(n),
                 "ITEM: BOX BOUNDS ff ff ff", "0 50", "0 50", "0 50",
                 "ITEM: ATOMS id type x y z"]
        lines += [f"{i + 1} 1 {p[0]:.6f} {p[1]:.6f} {p[2]:.6f}" for i, p in enumerate(xx)]
        return "\n".join(lines) + "\n"

    y = x.copy()
    cut = y[:, 1] > 3.0  # split along a line y = 3, perpendicular to y
    y[cut, 1] += 2.0
    p = tmp_path / "t.dump"
    p.write_text(frame(0, x) + frame(100, y))
    dd = dump_damage(p, bond_cutoff=2.0, break_cutoff=2.1, periodic_z=False)
    assert dd.frames == 2 and dd.first_damage_frame == 1
    assert np.all(dd.mu_fn[0] == 0)
    # exactly the atoms with a bond crossing y = 3 are damaged, by 1/T_i each
    pairs = bond_network(x, 2.0)
    crossing = cut[pairs[:, 0]] != cut[pairs[:, 1]]
    expect = np.zeros(n)
    T = np.bincount(pairs.ravel(), minlength=n)
    for i, j in pairs[crossing]:
        expect[i] += 1.0 / T[i]
        expect[j] += 1.0 / T[j]
    assert np.allclose(dd.mu_fn[1], expect)


def test_split_along_axis_separates_two_crack_rings():
    from upscale.analysis.damage import split_along_axis

    z = np.array([50.1, 110.0, 49.0, 111.2, 50.5, 109.5])
    groups = split_along_axis(z, gap=5.0)
    assert [sorted(g.tolist()) for g in groups] == [[0, 2, 4], [1, 3, 5]]
    assert split_along_axis([]) == []


def test_dump_positions_are_absolute_lammps_coordinates(tmp_path):
    """MDAnalysis shifts each frame's box to the origin; dump_damage undoes it."""
    x = np.array([[1.0, 2.0, 3.0], [2.4, 2.0, 3.0]])

    def frame(step, lo, xx):
        return "\n".join(["ITEM: TIMESTEP", str(step), "ITEM: NUMBER OF ATOMS", "2",
                          "ITEM: BOX BOUNDS ss ss ss", f"{lo} 10", f"{lo} 10", f"{lo} 10",
                          "ITEM: ATOMS id type x y z"]
                         + [f"{i + 1} 1 {p[0]} {p[1]} {p[2]}" for i, p in enumerate(xx)]) + "\n"

    p = tmp_path / "s.dump"
    p.write_text(frame(0, -5.0, x) + frame(10, -50.0, x + [0, 0, 0.5]))
    dd = dump_damage(p, periodic_z=False)
    assert np.allclose(dd.x_first_nc, x)
    assert np.allclose(dd.x_last_nc, x + [0, 0, 0.5])


def test_curve_metrics_single_flat_interval_then_rise_is_flagged():
    # a standard-cutoff shape sampled at 2 %: 127.5 @ 28 %, 129.47 @ 30 %, 129.55 @ 32 %,
    # then a steep rise to 235 GPa and a break
    e = np.round(np.arange(0, 0.50, 0.02), 4)
    s = np.concatenate([1000 * e[:2], np.linspace(39.4, 127.5, 13), [129.47, 129.55],
                        np.linspace(134.8, 234.9, 6), [6.1, 6.5]])
    assert len(s) == len(e)
    m = curve_metrics(e, s)
    assert m["rise_after_plateau"] and m["failed"]
    assert m["strength_GPa"] == pytest.approx(129.47)
    assert m["strain_at_peak"] == pytest.approx(0.30)
    assert m["max_stress_before_failure_GPa"] == pytest.approx(234.9)


def test_curve_metrics_failure_from_strain():
    """A dip before ``failure_from_strain`` is not failure; the first drop after it is."""
    from upscale.analysis.stress import curve_metrics

    e = [0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07]
    s = [0.0, 10.0, 20.0, 17.0, 30.0, 40.0, 10.0, 5.0]  # dip at 0.03, break at 0.06
    plain = curve_metrics(e, s, plateau_fraction=0.0)
    assert plain["strength_GPa"] == 20.0 and plain["failure_strain"] == 0.03
    late = curve_metrics(e, s, plateau_fraction=0.0, failure_from_strain=0.045)
    assert late["strength_GPa"] == 40.0 and late["failure_strain"] == 0.06
    assert "at or after strain 0.045" in late["failure_criterion"]
