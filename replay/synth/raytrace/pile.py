"""Piles that physics made: parts dropped into the bin by a rigid-body simulation (MuJoCo).

The parts of one kind fall from a loose column above the bin onto its floor, its drafted walls and
each other, and the simulation runs until they rest (or a time limit). The collision shapes are the
parts' convex outlines as MuJoCo primitives (a sphere for the balls, a cylinder for a hexagon nut, a box for a
screw head, a capsule for a rod and a screw shaft, a cylinder for a sprocket's disc): close enough
for how parts stack and tilt, and fast
(the bores of the nuts and sprockets, the teeth and the hexagon's corners are in the rendered meshes
of :mod:`replay.synth.raytrace.meshes`, not in the collisions). Measured against the alternatives
(pybullet, MuJoCo with convex mesh pieces, the hand-made generator's height-field drop):
``docs/raytraced.md``.

Units: the simulation runs in metres and seconds; what it returns is in millimetres in the world
frame of :mod:`replay.synth.scene` (z up, the table top at z = 0).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from replay.presets import BIN, PART_KINDS, BinGeometry
from replay.synth.scene import BinPose, tilt_vector
from zcut.errors import ParameterError

#: volume of one part (mm³), from the dimensions in :mod:`replay.presets`
PART_VOLUME_MM3: dict[str, float] = {
    "spheres": 4.0 / 3.0 * np.pi * 10.0**3,
    "zinc_nuts": (np.sqrt(3.0) / 2.0 * 18.0**2 - np.pi * 5.25**2) * 10.8,
    "black_nuts": (np.sqrt(3.0) / 2.0 * 18.0**2 - np.pi * 5.25**2) * 10.8,
    "rods": np.pi * 8.0**2 * 80.0,
    "black_screws": np.pi * 6.0**2 * 40.0 + np.sqrt(3.0) / 2.0 * 18.0**2 * 7.5,
    "sprockets": (np.pi * (38.0**2 - 8.0**2) + 20 * 0.5 * (6.0 + 2.5) * 6.0) * 7.0,
}
#: share of the pile's volume the parts fill (random loose packing of such shapes); sets how many
#: parts a fill height needs
PACKING = 0.5
#: simulation step (s) and the longest simulated time (s)
TIME_STEP_S = 0.004
MAX_SIM_S = 1.5
#: (mm) the thickness of the bin floor's collision box under the floor's surface, in the first simulation of a pile
FLOOR_THICKNESS_MM = 10.0
#: (s) MuJoCo's default time constant of a contact's soft constraint (``solref="0.02 1"``, critically damped): not
#: written into the MJCF
_MUJOCO_CONTACT_TIME_S = 0.02
#: (s) the time constant of the contacts in the first simulation of a pile: MuJoCo's default
CONTACT_TIME_S = _MUJOCO_CONTACT_TIME_S
#: a pile whose first simulation went unstable (MuJoCo met NaN, Inf or a huge value in the parts' positions, velocities
#: or accelerations, warned "The simulation is unstable" and reset them to their start) or lost parts (under the
#: floor, through or over a wall: :func:`lost_parts`) is simulated again from the same start with each of these in
#: turn, (floor thickness mm, time step divisor, contact time constant s), until a simulation is stable and keeps
#: every part: a floor the parts cannot pass through (a rod falling from the top of its column meets the floor at
#: ~4.5 m/s, 18 mm a step of 4 ms: it passes through 10 mm), a smaller step and stiffer contacts (at MuJoCo's default
#: 20 ms the rods of a 1 m column sink into a 100 mm floor and stay there, 1 to 8 a pile, at any step; at 8 ms and
#: 2 ms they stay on it); unstable at every one: :class:`UnstablePile`; losing parts at every one: the one that lost
#: the fewest (the later of a tie) is kept and the pile says so (``Pile.escaped``, ``Pile.lossy``). docs/raytraced.md,
#: the sections of the rounds of 2026-12-07a and 2026-12-07b
RETRIES = ((100.0, 2, 0.008), (100.0, 4, 0.008), (100.0, 4, 0.004))
#: (mm) a part whose origin ends deeper than this under the floor's surface went through the floor
UNDER_FLOOR_MM = 1.0
#: the pile rests when no part moves faster than this (m/s)
REST_SPEED_M_S = 0.02
#: a pile against the walls (``walls``): gravity tilted by this angle towards them for
#: :data:`WALL_TILT_S`, then vertical until the pile rests. Steeper than the hand-made generator's 15°
#: (:data:`replay.synth.scene.WALL_TILT_DEG`, which has no friction): at friction 0.4 a part slides
#: only on a slope steeper than atan(0.4) = 21.8°, so 15° would move the balls alone.
WALL_TILT_DEG = 30.0
WALL_TILT_S = 0.8


@dataclass(frozen=True, slots=True)
class UnstableRun:
    """A simulation of a pile that went unstable and was thrown away (:data:`RETRIES`).

    Attributes
    ----------
    time_step_s : float
        Its time step (s).
    floor_thickness_mm : float
        The thickness of its bin floor's collision box (mm).
    at_s : float
        Simulated time (s) when MuJoCo first found the state unstable (the run stopped there).
    warning : str
        MuJoCo's warning then, its own words ("Nan, Inf or huge value in QACC at DOF 442. The simulation is
        unstable. Time = 1.4800.").
    contact_time_s : float
        The time constant of its contacts (s; :data:`CONTACT_TIME_S` or a retry's).
    """

    time_step_s: float
    floor_thickness_mm: float
    at_s: float
    warning: str
    contact_time_s: float = CONTACT_TIME_S


@dataclass(frozen=True, slots=True)
class LossyRun:
    """A stable simulation of a pile that lost parts and was thrown away for a later one (:data:`RETRIES`).

    Attributes
    ----------
    time_step_s : float
        Its time step (s).
    floor_thickness_mm : float
        The thickness of its bin floor's collision box (mm).
    lost : int
        Parts it lost (not in the bin when it ended: :func:`lost_parts`).
    under_floor : int
        Of those, the parts that ended under the floor (went through it).
    contact_time_s : float
        The time constant of its contacts (s; :data:`CONTACT_TIME_S` or a retry's).
    """

    time_step_s: float
    floor_thickness_mm: float
    lost: int
    under_floor: int
    contact_time_s: float = CONTACT_TIME_S


class UnstablePile(ParameterError):
    """The pile's simulation went unstable in every way :data:`RETRIES` tries (one line; :attr:`runs` the
    simulations thrown away)."""

    def __init__(self, message: str, runs: tuple[UnstableRun, ...]) -> None:
        super().__init__(message)
        self.runs = runs


@dataclass(frozen=True, slots=True)
class Pile:
    """Where the dropped parts came to rest.

    Attributes
    ----------
    kind : str
        Part kind (key of :data:`PART_KINDS`).
    R : (n, 3, 3) float64 ndarray
        Rotation of each part, local -> world.
    t_mm : (n, 3) float64 ndarray
        World position of each part's origin (mm; z up, the table top at 0).
    sim_s : float
        Simulated time until the pile rested (or the limit).
    rested : bool
        Whether every part came to rest before :data:`MAX_SIM_S`.
    escaped : int
        Parts lost from the bin in the simulation kept (under its floor, through or over a wall, still above it:
        :func:`lost_parts`); they are removed from ``R`` and ``t_mm``. Nonzero only when every simulation tried lost
        some (:data:`RETRIES`).
    warnings : tuple of str
        What MuJoCo warned of while the pile settled (the simulation kept: never that it is unstable), in
        order; kept here instead of the ``MUJOCO_LOG.TXT`` MuJoCo would otherwise write into the working
        directory (:func:`mujoco_warnings`).
    time_step_s : float
        The time step (s) of the simulation kept: :data:`TIME_STEP_S`, or a divided one (:data:`RETRIES`).
    floor_thickness_mm : float
        The thickness of the bin floor's collision box in the simulation kept (mm): :data:`FLOOR_THICKNESS_MM`, or
        a retry's (:data:`RETRIES`).
    unstable : tuple of UnstableRun
        The simulations of the same start thrown away because they went unstable, in order (empty: the
        first one was stable and is the one kept).
    lossy : tuple of LossyRun
        The stable simulations of the same start that lost parts and were not kept, in order.
    under_floor : int
        Of ``escaped``, the parts that ended under the floor's surface (went through the floor).
    contact_time_s : float
        The time constant of the contacts in the simulation kept (s): :data:`CONTACT_TIME_S`, or a retry's.
    """

    kind: str
    R: np.ndarray
    t_mm: np.ndarray
    sim_s: float
    rested: bool
    escaped: int
    warnings: tuple[str, ...] = ()
    time_step_s: float = TIME_STEP_S
    floor_thickness_mm: float = FLOOR_THICKNESS_MM
    unstable: tuple[UnstableRun, ...] = ()
    lossy: tuple[LossyRun, ...] = ()
    under_floor: int = 0
    contact_time_s: float = CONTACT_TIME_S

    def __len__(self) -> int:
        return int(self.t_mm.shape[0])


@contextlib.contextmanager
def mujoco_warnings() -> Iterator[list[str]]:
    """MuJoCo's warnings while the block runs, collected in the list it yields instead of printed and
    appended to ``MUJOCO_LOG.TXT`` in the working directory (MuJoCo's default without a handler); the
    handler in place before is restored on exit."""
    import mujoco

    got: list[str] = []
    before = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(got.append)
    try:
        yield got
    finally:
        mujoco.set_mju_user_warning(before)


def part_count(kind: str, fill_mm: float, geometry: BinGeometry = BIN) -> int:
    """How many parts of ``kind`` fill the bin's floor to ``fill_mm`` on average (at :data:`PACKING`)."""
    fx, fy = geometry.floor_half
    return max(1, int(round(fill_mm * 4.0 * fx * fy * PACKING / PART_VOLUME_MM3[kind])))


def lost_parts(p_bin_mm: np.ndarray, *, radius_mm: float, geometry: BinGeometry = BIN) -> tuple[np.ndarray, int]:
    """Which parts a settled pile lost: their origins ``p_bin_mm`` ((n, 3) float, bin frame, mm) under the floor (deeper
    than :data:`UNDER_FLOOR_MM`), beside the bin (through or over a wall: farther out than the floor's half size plus
    10 mm a degree of draft) or above it (higher than the rim by 3 bounding radii ``radius_mm``).

    Returns
    -------
    lost : (n,) bool ndarray
        The parts the bin does not hold.
    under_floor : int
        How many of them are under the floor.
    """
    fx, fy = geometry.floor_half
    margin = 10 * geometry.draft_deg
    under = p_bin_mm[:, 2] <= geometry.floor_mm - UNDER_FLOOR_MM
    inside = ((np.abs(p_bin_mm[:, 0]) < fx + margin) & (np.abs(p_bin_mm[:, 1]) < fy + margin) & ~under
              & (p_bin_mm[:, 2] < geometry.height_mm + 3 * radius_mm))
    return ~inside, int(under.sum())


def _geoms(kind: str) -> str:
    """MJCF geoms of one part in its local frame (metres), the rendered meshes' convex outlines."""
    mm = 0.001
    x_axis = 'quat="0.7071068 0 0.7071068 0"'  # local z of the cylinder along the part's x
    if kind == "spheres":
        return f'<geom type="sphere" size="{10 * mm}"/>'
    if kind in ("zinc_nuts", "black_nuts"):
        return f'<geom type="cylinder" size="{9.5 * mm} {5.4 * mm}"/>'
    if kind == "rods":
        return f'<geom type="capsule" size="{8 * mm} {32 * mm}" {x_axis}/>'
    if kind == "black_screws":
        return (f'<geom type="capsule" size="{6 * mm} {17 * mm}" pos="{6.75 * mm} 0 0" {x_axis}/>'
                f'<geom type="box" size="{3.75 * mm} {8.7 * mm} {8.7 * mm}" pos="{-20 * mm} 0 0"/>')
    if kind == "sprockets":
        return f'<geom type="cylinder" size="{41 * mm} {3.5 * mm}"/>'
    raise KeyError(kind)


def _bin_geoms(geometry: BinGeometry, floor_thickness_mm: float = FLOOR_THICKNESS_MM) -> str:
    """MJCF geoms of the bin in the bin frame (metres): floor (a box ``floor_thickness_mm`` thick under the floor's
    surface) and four drafted inner walls."""
    mm = 0.001
    fx, fy = geometry.floor_half
    d = np.radians(geometry.draft_deg)
    t = 20.0  # wall thickness (mm)
    # the walls rise 1 m, a chute: parts dropped from high up cannot bounce out of the bin
    slant = 1000.0
    h = 0.5 * floor_thickness_mm
    out = [f'<geom type="box" size="{(fx + 50) * mm} {(fy + 50) * mm} {h * mm}" '
           f'pos="0 0 {(geometry.floor_mm - h) * mm}"/>']
    for axis, half in ((0, fx), (1, fy)):
        for sign in (1.0, -1.0):
            # the wall's inner face passes through the floor edge and leans out by the draft
            cz = geometry.floor_mm + 0.5 * slant * np.cos(d)
            ci = sign * (half + 0.5 * slant * np.sin(d) + 0.5 * t / np.cos(d))
            ang = sign * d
            if axis == 0:
                pos = f"{ci * mm} 0 {cz * mm}"
                size = f"{t / 2 * mm} {(fy + 60) * mm} {slant / 2 * mm}"
                quat = f"{np.cos(ang / 2)} 0 {np.sin(ang / 2)} 0"
            else:
                pos = f"0 {ci * mm} {cz * mm}"
                size = f"{(fx + 60) * mm} {t / 2 * mm} {slant / 2 * mm}"
                quat = f"{np.cos(-ang / 2)} {np.sin(-ang / 2)} 0 0"
            out.append(f'<geom type="box" size="{size}" pos="{pos}" quat="{quat}"/>')
    return "".join(out)


def _random_quaternions(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 4) uniformly random unit quaternions (w, x, y, z)."""
    q = rng.standard_normal((n, 4))
    unit: np.ndarray = q / np.linalg.norm(q, axis=1, keepdims=True)
    return unit


def _quat_to_R(q: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions (w, x, y, z) -> (n, 3, 3) rotations."""
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def drop_parts(
    kind: str,
    pose: BinPose,
    rng: np.random.Generator,
    *,
    count: int,
    geometry: BinGeometry = BIN,
    max_sim_s: float = MAX_SIM_S,
    walls: tuple[str, ...] = (),
) -> Pile:
    """Drop ``count`` parts of ``kind`` into the bin at ``pose`` and let them come to rest.

    The parts start in a loose column above the bin floor (one per cell of a grid as wide as the
    part, random orientation, a random sideways nudge) and fall under gravity; friction 0.4 (steel
    on steel, steel on plastic, dry). Deterministic: the same ``rng`` state gives the same pile.

    ``walls`` (of :data:`replay.synth.scene.WALL_SETS`; empty: straight down) piles them against
    those walls: for the first :data:`WALL_TILT_S` gravity is tilted by :data:`WALL_TILT_DEG`
    towards them (a bin tilted while it is filled), so the
    parts slide and roll there; then it turns vertical and the pile settles as it is (the walls
    hold it; friction keeps it heaped), for up to ``max_sim_s`` more.

    A simulation that goes unstable (MuJoCo resets the parts to their start and warns "The simulation is
    unstable") is thrown away and the same start simulated again with a thicker floor, then smaller time steps
    (:data:`RETRIES`); the pile says so (``Pile.unstable``, ``Pile.floor_thickness_mm``, ``Pile.time_step_s``). So is
    a stable simulation that lost parts (:func:`lost_parts`: mostly through the floor), until one keeps them all;
    when none does, the one that lost the fewest is kept (``Pile.escaped``, ``Pile.under_floor``, ``Pile.lossy``). A
    pile whose first simulation is stable and keeps every part is that simulation's, as before the retries existed.

    Raises
    ------
    ParameterError
        ``kind`` unknown, ``count`` < 1, or the part does not fit the bin's floor.
    UnstablePile
        (a ParameterError) The simulation went unstable at every time step tried.
    """
    if kind not in PART_KINDS:
        raise ParameterError(f"kind must be one of {', '.join(PART_KINDS)}, got {kind!r}")
    if int(count) != count or count < 1:
        raise ParameterError(f"count must be a positive integer, got {count!r}")
    r = PART_KINDS[kind].bounding_radius_mm
    fx, fy = geometry.floor_half
    if 2 * r >= 2 * min(fx, fy):
        raise ParameterError(
            f"a {kind} part ({2 * r:g} mm across) is larger than the bin's floor "
            f"({2 * fx:g} x {2 * fy:g} mm)")
    cell = 2.0 * r * 1.05
    nx, ny = max(1, int((2 * fx - 2) // cell)), max(1, int((2 * fy - 2) // cell))
    per_layer = nx * ny
    n = int(count)
    idx = np.arange(n)
    layer, k = idx // per_layer, idx % per_layer
    gx = (k % nx - (nx - 1) / 2) * cell
    gy = (k // nx - (ny - 1) / 2) * cell
    gz = geometry.floor_mm + r + 2.0 + layer * cell
    jitter = rng.uniform(-0.02, 0.02, (n, 2)) * cell
    start = np.c_[gx + jitter[:, 0], gy + jitter[:, 1], gz] / 1000.0
    quat = _random_quaternions(n, rng)
    vel = np.c_[rng.normal(0.0, 0.05, (n, 2)), np.zeros(n)]
    body = _geoms(kind)
    bodies = "".join(
        f'<body pos="{p[0]!r} {p[1]!r} {p[2]!r}" quat="{q[0]!r} {q[1]!r} {q[2]!r} {q[3]!r}">'
        f'<freejoint/>{body}</body>'
        for p, q in zip(start.tolist(), quat.tolist())
    )
    thrown: list[UnstableRun] = []
    stable: list[LossyRun] = []
    kept: tuple[_Run, np.ndarray, int, LossyRun] | None = None
    for floor_mm, divisor, contact_s in ((FLOOR_THICKNESS_MM, 1, CONTACT_TIME_S), *RETRIES):
        # the first stable simulation that keeps every part is the pile's
        dt = TIME_STEP_S / divisor
        world = f'<worldbody>{_bin_geoms(geometry, floor_mm)}{bodies}</worldbody>'
        run = _settle(world, n, vel, time_step_s=dt, max_sim_s=max_sim_s, walls=walls, contact_time_s=contact_s)
        if run.unstable is not None:
            thrown.append(dataclasses.replace(run.unstable, floor_thickness_mm=floor_mm, contact_time_s=contact_s))
            continue
        lost, under = lost_parts(run.qpos[:, :3] * 1000.0, radius_mm=r, geometry=geometry)
        record = LossyRun(dt, floor_mm, int(lost.sum()), under, contact_s)
        stable.append(record)
        if kept is None or record.lost <= kept[3].lost:  # the later of a tie: a thicker floor, a smaller step
            kept = (run, lost, under, record)
        if record.lost == 0:
            break
    if kept is None:
        tried = ", ".join(f"{r.floor_thickness_mm:g} mm floor at {r.time_step_s * 1000:g} ms" for r in thrown)
        raise UnstablePile(f"the pile's simulation ({n} {kind}) went unstable in every way tried ({tried}; MuJoCo: "
                           f"{thrown[-1].warning.rstrip('.')}); try another seed", tuple(thrown))
    run, lost, under, record = kept
    qpos = run.qpos
    p_bin = qpos[:, :3] * 1000.0
    R_bin = _quat_to_R(qpos[:, 3:])
    inside = ~lost
    # bin frame -> world: yaw about z, then the bin's offset
    c, s = np.cos(pose.yaw_rad), np.sin(pose.yaw_rad)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    t_world = p_bin[inside] @ Rz.T + np.array([pose.x_mm, pose.y_mm, 0.0])
    R_world = np.einsum("ij,njk->nik", Rz, R_bin[inside])
    return Pile(kind, R_world, t_world, run.sim_s, run.rested, record.lost, run.warnings, record.time_step_s,
                record.floor_thickness_mm, tuple(thrown), tuple(x for x in stable if x is not record), under,
                record.contact_time_s)


@dataclass(frozen=True, slots=True)
class _Run:
    """One simulation of a pile (:func:`_settle`): the parts' final (n, 7) ``qpos`` (bin frame, m; w, x, y, z),
    the simulated time, whether it rested, MuJoCo's warnings, and what made it unstable (None: stable)."""

    qpos: np.ndarray
    sim_s: float
    rested: bool
    warnings: tuple[str, ...]
    unstable: UnstableRun | None


#: MuJoCo's warnings of an unstable simulation (it resets the state when it raises one)
_UNSTABLE = ("mjWARN_BADQPOS", "mjWARN_BADQVEL", "mjWARN_BADQACC")


def _settle(world: str, n: int, vel: np.ndarray, *, time_step_s: float, max_sim_s: float,
            walls: tuple[str, ...], contact_time_s: float = CONTACT_TIME_S) -> _Run:
    """Simulate the ``n`` parts of the MJCF ``world`` from rest but their sideways velocities ``vel`` (m/s) with
    ``time_step_s`` and contacts of time constant ``contact_time_s`` until they rest or ``max_sim_s`` (after the
    tilt, with ``walls``); stops at the first step after which MuJoCo counts a warning of an unstable state
    (:data:`_UNSTABLE`)."""
    import mujoco

    # MuJoCo's default contacts are not written: the first simulation's MJCF is the one of before the retries
    solref = "" if contact_time_s == _MUJOCO_CONTACT_TIME_S else f' solref="{contact_time_s!r} 1"'
    xml = (
        f'<mujoco><option timestep="{time_step_s}" gravity="0 0 -9.81" solver="PGS" jacobian="sparse" iterations="30"/>'
        f'<default><geom friction="0.4 0.005 0.0001" density="7800" condim="3"{solref}/></default>'
        f'{world}</mujoco>'
    )
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.qvel.reshape(n, 6)[:, :3] = vel
    steps = int(round(max_sim_s / time_step_s))
    tilted = 0
    if walls:
        gu, gv = tilt_vector(tuple(walls), WALL_TILT_DEG)
        cos_t = float(np.cos(np.radians(WALL_TILT_DEG)))
        model.opt.gravity[:] = (9.81 * cos_t * gu, 9.81 * cos_t * gv, -9.81 * cos_t)
        tilted = int(round(WALL_TILT_S / time_step_s))
        steps += tilted
    check = max(1, int(round(0.05 / time_step_s)))
    bad = [int(getattr(mujoco.mjtWarning, w)) for w in _UNSTABLE]
    rested = False
    unstable = None
    i = 0
    with mujoco_warnings() as warned:
        for i in range(1, steps + 1):
            if i == tilted + 1 and tilted:
                model.opt.gravity[:] = (0.0, 0.0, -9.81)
            mujoco.mj_step(model, data)
            if any(data.warning[w].number for w in bad):  # reset to the start by MuJoCo: thrown away
                unstable = UnstableRun(time_step_s, float("nan"), i * time_step_s, warned[-1] if warned else "unstable")
                break
            if i % check == 0 and (i - tilted) * time_step_s > 0.3:
                if float(np.abs(data.qvel.reshape(n, 6)[:, :3]).max()) < REST_SPEED_M_S:
                    rested = True
                    break
    return _Run(data.qpos.reshape(n, 7).copy(), i * time_step_s, rested, tuple(warned), unstable)
