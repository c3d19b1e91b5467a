"""The particle engine every model shares.

CONTRACT (stable; changes are additive only)
============================================

Units: whatever a scene uses, consistently; continuum scenes are SI (m, kg, s, Pa, J),
the tube scenes Å, fs, eV (``ParticleSystem(units="atomic")``, which labels the messages).
Array suffix convention in kernels: ``_n`` per particle, ``_b`` per directed bond,
``_c`` Cartesian component. Positions always have 3 components (2D: z = 0, 1D: y = z = 0).

``upscale.engine.system``
    ``ParticleSystem(x0 (N,3), volume (N,)|scalar, density=(N,)|scalar, material=None,
    *, dim=3, thickness=None, plane="stress", spacing=None, units="si")``. Attributes
    ``x0, volume, density, material (int32), dim, thickness, plane, n, mass, spacing,
    units, time_unit, energy_unit``.
    2D: ``volume`` = area x ``thickness`` (m^3). Bad input (NaN position, non-positive
    volume/density, wrong shape) -> one-line ``ValueError`` naming the value.
    ``system.select(where=pred, box=(lo, hi), name=...) -> bool (N,)`` raises if the
    region selects nothing. Builders: ``cubic_lattice(nx, ny, nz, h, density=...)``,
    ``square_lattice(nx, ny, h, thickness=..., plane=...)``, ``line_lattice(nx, h)``.

``upscale.engine.families``
    ``build_family(system, horizon, *, partial_volume=None|"lammps"|"linear",
    spacing=None, exclude=None) -> Family`` (cKDTree). ``Family`` has CSR arrays holding
    *both* directions of each bond: ``offsets (N+1,) int64``, ``neighbors (nb,) int32``
    (int64 from 2^31 particles), the reference positions ``x0``, ``horizon``, ``spacing``;
    computed on each access (kept nowhere): ``xi (nb,3)`` = ``x0[j] - x0[i]``,
    ``length (nb,)``, ``volume_factor (nb,)`` (beta, 1 unless corrected), ``owner (nb,)``
    (i of each bond), ``reverse (nb,)`` (index of j->i), and for a subset of bonds
    ``xi_of, length_of, volume_factor_of, owner_of``; ``n, nb, counts``, ``pairs()``,
    ``bond_blocks(size)``, ``nbytes()``, ``remove_bonds(mask) -> Family`` (pre-cracks that
    LAMMPS-style never exist).
    Horizon not larger than the spacing -> ``ValueError``.
    Bond state is ``intact (nb,) bool``; ``damage(family, intact, weights="count"|"volume",
    volume=None) -> mu (N,)``, mu = 1 - R/T (seed 004 eq. 5.16).
    ``bonds_crossing_segment(x0, a, b)`` -> an ``exclude`` callable for straight cracks.
    Higher families (triplets, quadruplets) are built from the pair CSR by
    ``upscale.engine.multibody`` when a model's ``needs`` asks for them.

``upscale.engine.bondlist``
    ``BondList(family, volume)``: the pair loops' layout, derived from a family once in a
    model's ``prepare`` (each pair once, unsigned 32-bit partners, a reference-geometry
    class per pair, the directed index of the reverse bond; the bond state stays
    ``state.intact``); ``classes(*factors_b)``, ``chunks(nthreads)``, ``target(out,
    nthreads)`` / ``finish`` (per-thread buffers), ``stream_bytes()``.

``upscale.engine.state``
    ``State(x0, y, v, intact, t=0, step=0, extra={}, fields={}, field_v={})``;
    ``State.reference(x0, nb)``;
    ``state.u`` (= y - x0, settable). ``y`` (current positions) is the primary variable.
    ``extra`` holds model history arrays that checkpoints save.

``upscale.models.base`` (the model side of the contract)
    ``Needs(pairs=True, triplets=False, quadruplets=False, failure=False, energy=False,
    tangent=False)``. ``Model`` with class attributes ``name``, ``needs``,
    ``force_kind`` ("density": force density b in N/m^3, particle force is b*V and
    acceleration b/rho; or "particle": force per particle, acceleration F/(rho*V)).
    Methods: ``prepare(system, family, *, triplets=None, quadruplets=None)``,
    ``init_state(state)``, ``add_force(state, out)`` (adds into out (N,3)),
    ``break_bonds(state) -> int`` (mutates ``state.intact``),
    ``step_force(state, out, failure=True) -> int`` (force, then failure from the same
    positions: the LAMMPS order), ``force(state)``, ``energy_density(state) -> (N,)`` J/m^3,
    ``energy(state) -> float`` J, ``particle_force(state) -> (N,3)`` N,
    ``residual(state) -> (3N,)`` (= F_int flattened), ``tangent(state) -> scipy.sparse``
    (K = -dF_int/dy), ``stiffness_bound() -> (N,)|None`` (Gershgorin row bound of
    d(force)/dy, used for the stable step), ``stable_dt()``, ``describe() -> dict``.
    Registry: ``upscale.models.register(name, cls)``, ``get(name)``, ``create(name,
    **params)``, ``names()``; unknown name -> ``ValueError`` listing valid names.

``upscale.engine.conditions``
    ``Region(name, mask)`` / ``region(system, name, where=None, box=None)``; conditions
    ``Fixed(region)``, ``Displacement(region, value, components=(0,1,2))``,
    ``Velocity(region, value, components)``, ``Force(region, value)`` (N per particle),
    ``BodyForce(region, value)`` (N/m^3); ``value`` is a 3-vector, an (n_region, 3)
    array, or a callable ``f(t) -> either``, so any condition may depend on time.
    ``Grip(region, velocity=None, displacement=None, u0=0, components, record_every=1)``:
    the region moved rigidly (``u0 + velocity t``) or held; after every force evaluation
    ``grip.reaction_now`` (3,) = ``-sum_{region} F_i`` (the force it exerts on the body)
    and ``grip.history`` [(t, reaction)].

``upscale.engine.integrators``
    ``VelocityVerlet(dt=None, safety=0.8, force=False)`` (dt None: safety x estimate; a
    dt above the estimate is refused unless ``force=True``);
    ``AdaptiveDynamicRelaxation(dt=1.0, tol=..., max_steps=...)`` (Underwood/Kilic-Madenci
    ADR for quasi-static loading); ``stable_time_step(system, models) -> float``.
    Newton-Raphson lives in ``upscale.engine.newton`` on the models'
    ``residual`` / ``tangent`` hooks; ``solve(..., checkpoint=path, resume=False)``
    checkpoints after every converged load step and resumes bit for bit.
    ``VelocityVerlet(..., thermostat=None)``; an integrator may provide
    ``checkpoint_arrays() -> dict`` / ``restore_arrays(dict)`` for its own variables.

``upscale.engine.respa`` (multiple time stepping, a peer of ``VelocityVerlet``)
    ``RESPA(outer_dt, inner=1, thermostat=None, force=False)``: r-RESPA (Tuckerman, Berne &
    Martyna 1992, impulse form): half kick with the slow forces, ``inner`` velocity
    Verlet steps of ``outer_dt / inner`` with the fast ones, half kick with the slow
    forces; ``sim.run(k)`` runs k outer steps; ``RESPA.dt`` is the inner step (the blow-up
    guard's); ``checkpoint_arrays`` / ``restore_arrays`` hold both groups' forces and the
    thermostat, so a resumed run continues bit for bit. The force split is the models'
    (optional, additive): ``add_group_force(state, out, group)``,
    ``add_group_field_force(state, out, group)``, ``group_energy(state, group)`` for
    ``group`` in ``("fast", "slow")``, each pair summing to ``add_force`` /
    ``add_field_force`` / ``energy`` (an exact split of one energy); a model without them
    is fast as a whole; ``prepare_split(state)`` (optional) re-chooses the split about the
    current state, called by ``RESPA.update_forces(sim)``, which a scene calls instead of
    ``sim.update_forces()`` after changing a model between steps (links, dead loads).

``upscale.engine.thermostats``
    ``Langevin(temperature, damping, region=None, seed=0, k_B=None)`` (Ornstein-Uhlenbeck
    step after the second half-kick) and ``NoseHooverChain(temperature, tau, region=None,
    chain=3, k_B=None)`` (MTK Trotter half-steps around the step); pass one as
    ``VelocityVerlet(..., thermostat=...)``. ``region``: a Region or (N,) bool (default
    all); only its free dofs are thermostatted. ``k_B`` in the scene's energy per K
    (default SI; ``upscale.constants.K_B_EV`` for eV). ``kinetic_temperature(sim, region,
    k_B)``. Their variables and random state are part of the checkpoint.
    ``NoseHoover(temperature, tau, region=None, components=(0, 1, 2), fields=(),
    field_region=None, ndf=None, k_B=None)``: one Nose-Hoover variable in explicit half
    steps, on chosen translation components (``(0, 1)``: LAMMPS's ``temp/partial 1 1 0``)
    and on fields with inertia (their rates count in the temperature and are scaled).

``upscale.engine.minimisers`` (peers of the integrators)
    ``FIRE(ftol, max_iter, dt=None, ...)``, ``QuickMin(ftol, max_iter, dt=None)``,
    ``LBFGS(ftol, max_iter, memory=10, bounds=(lo, hi))`` (scipy L-BFGS-B); each has
    ``minimise(sim, raise_on_fail=True, checkpoint=None, resume=False) -> MinimiseResult``
    (``method, converged, iterations, fmax, energy, n_force, wall_s, message, history``),
    also as ``sim.minimise(minimiser)``. They relax the free dofs of ``sim.state.y`` on
    the total potential ``sum E_models - F_ext . u`` (forces: ``sim.forces()``), bonds do
    not break. Not converged in ``max_iter``: ``NotConverged`` (one line: method, fmax vs
    ftol, iterations; ``.result``), the state left at the last finite iterate. FIRE and
    QuickMin resume bit for bit from their checkpoint; L-BFGS-B resumes from its iterate
    with a new curvature history. Massless internal fields (per-particle arrays in
    ``state.extra`` a model relaxes at every configuration, e.g. the tube's sublattice
    shifts): a model declares ``internal_fields = {name: (lo, hi)}`` and provides
    ``internal_gradient(state) -> {name: dE/dfield}`` and ``hold_internal(flag)``; L-BFGS-B
    then minimises them together with the positions (the model holds them meanwhile).
    Array level, for a model that is its own configuration space (the coarse tube: its
    particles, free atoms, shifts and cell length), each returning an ``ArrayMinimum``
    (``x, energy, iterations, n_force, converged, message``): ``lbfgs_b(fun, x0, lo, hi,
    gtol, max_iter, memory, ftol, maxfun)`` (``fun(x) -> (E, dE/dx)``; points off the
    domain get an infinite energy), ``bfgs(fun, x0, gtol, max_iter)``,
    ``quick_min_blocks(forces, blocks, masses, dt, steps, max_step, ftol, bounds, acc)``;
    strategies over them: ``restarted(result, restart, done, max_restarts)``,
    ``first_lower(starts, minimise, energy, below)``, ``zero_cell_force(relax, L, tol)``
    (secant on a cell length). The model supplies energy and gradient, the engine iterates.

``upscale.engine.bodies``
    ``Body(system, family, models, name)``; ``assemble(bodies, interactions=()) ->
    Assembly`` stacks them into one system (``system.body_n`` (N,) body index) and wraps
    each body model (``BodyModel``: the model sees its own rows, bonds and extras);
    ``interactions`` are models on the whole system acting between bodies (e.g.
    ``upscale.models.lennard_jones.LennardJonesBetweenBodies``). ``Assembly.rows(name)``,
    ``.mask(name)``, ``.simulation(conditions, integrator)``. Mismatched bodies (dim,
    plane, thickness) or repeated names -> ``ValueError``. A body model's fields are the
    assembled fields ``"<body>/<field>"`` (its field forces and ``particle_damage`` are
    forwarded too; ``BodyModel.sub(state)`` is the body's view of the assembled state).

``upscale.engine.simulation``
    ``Simulation(system, family, models, conditions=(), integrator=None, state=None,
    damage_weights="count")``: ``sim.state``, ``sim.forces() -> (N,3)`` particle forces
    (N), ``sim.internal_forces(failure=False)``, ``sim.update_forces()`` (sets ``sim.F``,
    ``sim.reactions``), ``sim.energy()``, ``sim.kinetic_energy()``, ``sim.damage()``,
    ``sim.constrained (N,3) bool``, ``sim.run(steps, output=None, checkpoint=None,
    progress=False, callback=None, meta=None)`` (``steps`` more steps; raises
    ``integrators.BlowUp`` with a diagnosis), ``sim.resume(path)``, ``sim.relax(adr)``,
    ``sim.minimise(minimiser)``, ``sim.external_forces()``; ``sim.damage()`` also takes a
    model's own ``particle_damage(state) -> (N,)`` (a model with its own links).
    ``sim.resume`` continues bit for bit: a checkpoint holds, besides the state,
    ``sim.checkpoint_arrays()`` (the last step's forces, reactions, counters, the time
    step, the integrator's and thermostat's variables), and no force is recomputed on
    resume (a recomputation would apply the failure criterion again at the same positions
    and drop the forces of the bonds broken in the last evaluation).
    The engine does only what the models' ``needs`` and the outputs ask for.

``upscale.engine.fields`` (generalised degrees of freedom)
    Per-particle fields beyond the translations with their own inertia (rotations of
    tridynamic beams and plates): ``state.fields[name]`` / ``state.field_v[name]``
    (N, k). A model declares ``fields() -> {name: FieldSpec(ncomp, inertia)}`` (inertia
    density, e.g. ``rho I/A``), adds generalised force densities in
    ``add_field_force(state, out)``, may give ``field_stiffness_bound() -> {name: (N,)}``
    (the stable step counts field rows with their inertia), ``translations`` (the
    translation components it acts on) and ``influence_radius()``. ``sim.G`` holds the
    field forces per particle; velocity Verlet kicks and drifts the fields; checkpoints
    save them. Conditions: ``FixedField(region, field, components)`` and
    ``Tie(region, masters, weights, target)`` (ghost dofs slaved to linear combinations:
    mirror supports, extrapolated ends). Linear tools: ``operator(sim)`` (K = -dF/dq by
    probing the force routines), ``solve_static(sim)`` (sparse LU, no symmetry assumed),
    ``critical_dt(sim)``. ``FixedField(..., hold=True)`` keeps the components' current
    values (only their rate is zeroed). Massless internal fields and global variables are
    not part of this extension.

``upscale.engine.dispersion``
    ``dynamical_matrix(sim, k)`` / ``dispersion(sim, ks)``: the discrete dispersion of any
    linear model from its force routine applied to plane waves.

``upscale.engine.output`` / ``upscale.engine.checkpoint``
    ``Output(outdir, every, formats=("extxyz", "vtk", "json"), energy=False)``: extxyz via
    ase.io with ``displacement``, ``velocity``, ``damage``, ``volume`` arrays (lengths in
    the unit ``length_unit_m`` of the frame info, because ASE writes ``%16.8f``), VTK via
    meshio, JSON summary. ``save_checkpoint(path, state, meta, engine=None)`` /
    ``load_checkpoint(path, x0=None, nb=None, engine=False) -> (state, meta[, engine])``,
    ``Checkpoint(path, every)``: npz written atomically; a killed run resumes from it.
    ``engine`` holds the driver's arrays (see ``Simulation.resume``).

``upscale.engine.kernels``
    generic numba kernels (damage, stretch, breaking, VV kick/drift) and
    ``set_threads(n)``.

``upscale.engine.lammps_peri``
    LAMMPS PERI (peri/pmb, peri/lps) as a reference: every convention and how the engine
    matches it (``LammpsPeri``); ``upscale.experiments.scenes.peri_lammps.compare(style, ...)``
    runs both.

Layering: ``upscale.engine`` imports neither ``upscale.models`` nor
``upscale.experiments`` (it knows models only by this contract); ``tests/test_layering.py``
walks the imports.
"""
from __future__ import annotations

from upscale.engine.families import Family, bonds_crossing_segment, build_family, damage
from upscale.engine.state import State
from upscale.engine.system import ParticleSystem, cubic_lattice, line_lattice, square_lattice

__all__ = [
    "ParticleSystem", "cubic_lattice", "square_lattice", "line_lattice",
    "Family", "build_family", "damage", "bonds_crossing_segment", "State",
    "Simulation",
]


def __getattr__(name):  # lazy: the simulation pulls in integrators, output, numba kernels
    if name == "Simulation":
        from upscale.engine.simulation import Simulation

        return Simulation
    raise AttributeError(f"module 'upscale.engine' has no attribute {name!r}")
