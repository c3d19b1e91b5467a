"""The MPI tier inside an MPI world: ``mpiexec -n 2 python -m pytest -m mpi
tests/test_parallel_mpi.py`` (``make test-mpi``). Every rank runs every test, in the same
order; the collectives of a test come before its asserts, so a failing rank does not leave
the other waiting. The serial reference is computed in the same processes
(:func:`upscale.engine.parallel.comm.serial`). Skipped on one process."""
import numpy as np
import pytest

from upscale.engine.parallel.comm import Refused, serial, world

pytestmark = [pytest.mark.mpi,
              pytest.mark.skipif(world().size < 2, reason="needs an MPI world of >= 2 ranks")]

N = 30


def _lean(n, model, thermostat=None):
    from parallel_plate_run import lean_plate

    return lean_plate(n, model, thermostat)


def _run(sim, steps):
    sim.run(steps)
    u = sim.gather(sim.state.u)
    intact = sim.state.intact if sim.part is None else sim.part.gather_bonds(sim.state.intact)
    return u, intact, sim.broken_bonds()


@pytest.mark.parametrize("model", ["pmb", "lps"])
def test_plate_built_rank_by_rank_equals_the_serial_plate(model):
    from upscale.engine.parallel import build_local
    from upscale.experiments.scenes.plate import PlateScene

    with serial():
        ref_u, ref_intact, ref_broken = _run(_lean(N, model), 400)
        whole = PlateScene(N, model=model).sim.family  # the whole family, to compare rows
    sim = _lean(N, model)
    loc = sim.part.local
    want = build_local(sim.part.comm, whole.offsets, whole.neighbors, sim.part.part, loc.depth)
    u, intact, broken = _run(sim, 400)
    assert ref_broken > 0 and broken == ref_broken
    assert np.array_equal(u, ref_u) and np.array_equal(intact, ref_intact)
    for k in ("gid", "owned", "offsets", "neighbors", "bond_gid"):
        assert np.array_equal(getattr(loc, k), getattr(want, k)), k


@pytest.mark.parametrize("kind", ["langevin", "nose-hoover", "nose-hoover-chain"])
def test_thermostatted_plate_on_ranks(kind):
    from upscale.engine import thermostats as T

    # 50 m/s on 1.7 mm particles of 8000 kg/m^3: a "temperature" of ~1e16 K, so a target
    # of 1e16 K makes the thermostat act on the run (not a round-off perturbation)
    make = {"langevin": lambda: T.Langevin(1e16, 2e5, seed=5),
            "nose-hoover": lambda: T.NoseHoover(1e16, 2e-6),
            "nose-hoover-chain": lambda: T.NoseHooverChain(1e16, 2e-6)}[kind]
    with serial():
        ref_u, ref_intact, _ = _run(_lean(N, "pmb", make()), 300)
        plain_u, _, _ = _run(_lean(N, "pmb"), 300)
    u, intact, _ = _run(_lean(N, "pmb", make()), 300)
    scale = float(np.abs(ref_u).max())
    assert float(np.abs(ref_u - plain_u).max()) > 1e-3 * scale  # the thermostat acted
    if kind == "langevin":  # every rank draws the serial stream: the same bits
        assert np.array_equal(u, ref_u) and np.array_equal(intact, ref_intact)
    else:  # the kinetic energy is a sum over ranks: the serial answer up to its order
        assert float(np.abs(u - ref_u).max()) <= 1e-12 * scale
        assert np.array_equal(intact, ref_intact)


def _square(model, n=30, steps=200):
    """A square of ``model`` pulled at 5 m/s at its top and bottom rows, run ``steps``
    steps: the whole body's displacements, bond states and broken bonds."""
    from upscale.engine import Simulation, square_lattice
    from upscale.engine.conditions import Velocity, region
    from upscale.engine.families import FamilyRecipe

    h = 1e-3
    s = square_lattice(n, n, h, thickness=h, density=8000.0, plane="stress", centered=True)
    L = n * h
    top = region(s, "top", box=((None, L / 2 - 3 * h, None), (None, None, None)))
    bottom = region(s, "bottom", box=((None, None, None), (None, -L / 2 + 3 * h, None)))
    conds = [Velocity(top, (0.0, 5.0, 0.0), components=(1,)),
             Velocity(bottom, (0.0, -5.0, 0.0), components=(1,))]
    return _run(Simulation(s, FamilyRecipe(s, 3.015 * h), model(h), conds), steps)


MODELS = {
    "nosb-silling": lambda h: _create("nosb", E=192e9, nu=1 / 3, stabilisation="silling"),
    "nosb-wan-svk-bond": lambda h: _create("nosb", E=192e9, nu=1 / 3, stabilisation="wan",
                                           law="svk", kernel="bond"),
    "cpd-c2-failure": lambda h: _create("cpd", horizon=3.015 * h, dim=2, E=192e9, nu=0.34,
                                        plane="stress", calibration="continuum", s1c=2e-3),
    "unified": lambda h: _create("unified"),
}


def _create(name, **kw):
    from upscale import models

    return models.create(name, **kw)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_models_of_families_on_ranks_are_bit_identical(name):
    with serial():
        ref_u, ref_intact, ref_broken = _square(MODELS[name])
    u, intact, broken = _square(MODELS[name])
    assert float(np.abs(ref_u).max()) > 0
    if name.startswith("cpd"):
        assert ref_broken > 0            # the failure criterion acted
        assert MODELS[name](1e-3).needs.triplets   # C2 > 0: the partners' sets count
    assert np.array_equal(u, ref_u) and np.array_equal(intact, ref_intact)
    assert broken == ref_broken


def _static_plate(n=24):
    from upscale import models
    from upscale.engine import Simulation, square_lattice
    from upscale.engine.conditions import Displacement, Fixed, region
    from upscale.engine.families import FamilyRecipe

    h = 1e-3
    s = square_lattice(n, n, h, thickness=h, density=8000.0, plane="stress", centered=True)
    L = n * h
    top = region(s, "top", box=((None, L / 2 - 3 * h, None), (None, None, None)))
    bottom = region(s, "bottom", box=((None, None, None), (None, -L / 2 + 3 * h, None)))
    conds = [Displacement(top, (0.0, 1e-6, 0.0), components=(1,)), Fixed(bottom)]
    return Simulation(s, FamilyRecipe(s, 3.015 * h), models.create("lps", E=1e9, nu=0.25),
                      conds)


def test_adaptive_dynamic_relaxation_on_ranks_reaches_the_serial_equilibrium():
    from upscale.engine.adr import FusedAdaptiveDynamicRelaxation as ADR

    tol = 1e-10
    with serial():
        sim = _static_plate()
        ref = sim.relax(ADR(tol=tol, max_steps=20000))
        ref_u = sim.state.u.copy()
    sim = _static_plate()
    got = sim.relax(ADR(tol=tol, max_steps=20000))
    u = sim.gather(sim.state.u)
    assert ref["converged"] and got["converged"]
    # the damping sums are added over ranks (another order than the serial sum): the same
    # equilibrium to the relaxation's tolerance, not the same iterates bit for bit
    assert float(np.abs(u - ref_u).max()) <= 100 * tol * float(np.abs(ref_u).max())


def test_single_process_paths_refuse_on_every_rank():
    from upscale import models
    from upscale.engine import newton
    from upscale.engine.state import State

    sim = _static_plate()
    with serial():
        whole = _static_plate()
    errors = []
    for call in (lambda: newton.solve(whole.models[0], State.reference(whole.system.x0,
                                                                       whole.family.nb)),
                 lambda: sim.minimise(),
                 lambda: sim.relax(checkpoint=None, resume=False)):
        try:
            call()
            errors.append(None)
        except Refused as exc:
            errors.append(str(exc))
    assert "implicit solve" in errors[0] and "runs on one process" in errors[0]
    assert "minimisers run on one rank" in errors[1]
    assert "FusedAdaptiveDynamicRelaxation" in errors[2]
    from upscale.engine import Simulation

    with pytest.raises(Refused, match="unified model with bond failure"):
        Simulation(whole.system, whole.family, models.create("unified", r_s=1e-3, G_c=100.0))


def test_more_ranks_than_particles_refused():
    from upscale import models
    from upscale.engine import Simulation
    from upscale.engine.families import FamilyRecipe
    from upscale.engine.system import ParticleSystem

    one = ParticleSystem(np.zeros((1, 3)), np.ones(1), 1.0, dim=2, thickness=1.0, spacing=1.0)
    with pytest.raises(Refused, match=f"{world().size} MPI ranks for 1 particles"):
        Simulation(one, FamilyRecipe(one, 2.0), models.create("pmb", E=1e9))


def test_checkpoint_of_another_rank_count_refused_with_the_way_to_convert(tmp_path):
    comm = world()
    d = comm.bcast(str(tmp_path))  # one folder for every rank (rank 0's)
    if comm.rank == 0:
        np.savez(f"{d}/ck.rank0of3.npz", step=np.int64(10))
    comm.barrier()
    sim = _lean(20, "pmb")
    with pytest.raises(Refused, match="written on 3 MPI ranks.*parallel.convert"):
        sim.resume(f"{d}/ck.npz")
