"""Dynamic sample scenes simulated with the XPBD solver of ``pbd.py``.

Every scene function has the signature ``scene(vertices, frames, seed)`` and
returns ``(positions, topology, attrs)``: positions ``(T, N, 3)`` float64,
topology a dict with ``edges`` and/or ``faces`` (and optionally
``components`` and ``obstacles``), attrs a dict with ``dt``, ``thickness``, for
contact scenes the simulator's ``contact_radius``, and a short description
(``generate.py`` adds the command line to it).

Thickness values are fractions of the smallest rest edge length that
``check.py`` showed to be kept by the recorded motion (README.md lists the
measured separations).
"""

from __future__ import annotations

import numpy as np
from scipy.special import j0, j1

from pbd import Solver, chain_constraints, chain_edges, grid_constraints, grid_faces


#: First zero of the Bessel function J0 (hanging-chain modes).
J0_ROOT = 2.404825557695773


def _rotate(vecs, axis, angle):
    """Rodrigues rotation of row vectors about unit `axis` by `angle` (broadcasts)."""
    axis = np.asarray(axis, float)
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    return vecs * c + np.cross(axis, vecs) * s + axis * (vecs @ axis)[..., None] * (1 - c)


def _hanging_chains(pins, length, per, amp, azim, ecc):
    """Polylines hanging from `pins`, bent in the first hanging-chain mode.

    The lateral offset is ``A J0(2.405 sqrt(z / L))`` with z measured from the
    free end (tip offset `amp`, direction `azim`); the initial velocity is the
    same mode shape sideways with speed ``ecc * amp * omega``, so each chain
    swings on an ellipse. Starting in the mode avoids a whipping tip.

    Returns
    -------
    x, v : (len(pins) * per, 3) float64
    """
    x, v = [], []
    for k in range(len(pins)):
        s = np.linspace(0, length[k], per)
        z = length[k] - 0.5 * (s[1:] + s[:-1])
        q = J0_ROOT * np.sqrt(z / length[k])
        slope = amp[k] * J0_ROOT * np.where(q > 1e-9, j1(q) / np.maximum(q, 1e-9), 0.5) \
            * J0_ROOT / (2 * length[k])
        phi = np.arctan(slope)
        out = np.array([np.cos(azim[k]), np.sin(azim[k]), 0.0])
        side = np.array([-np.sin(azim[k]), np.cos(azim[k]), 0.0])
        seg = (np.sin(phi)[:, None] * out + np.cos(phi)[:, None] * [0, 0, -1.0]) * (s[1] - s[0])
        x.append(pins[k] + np.vstack([np.zeros(3), np.cumsum(seg, axis=0)]))
        mode = j0(J0_ROOT * np.sqrt((length[k] - s) / length[k]))
        omega = 0.5 * J0_ROOT * np.sqrt(9.81 / length[k])
        v.append(mode[:, None] * (ecc[k] * amp[k] * omega) * side)
    return np.concatenate(x), np.concatenate(v)


def rods(vertices=2048, frames=48, seed=0):
    """Pinned strands (yarn-like polylines) swinging conically with different phases.

    32 strands hang from a 8 x 4 grid of pins 0.3 m apart; lengths 0.35-0.55 m.
    Each starts bent in the first hanging-chain mode (tip offset 4-7 cm, random
    azimuth) with a sideways push in the same mode, so it swings on an ellipse
    whose shape and period differ per strand; the pin plate circles gently
    (1 cm, 0.7 Hz), which excites higher modes. Soft bending, slight stretch.
    """
    rng = np.random.default_rng(seed)
    # 32 strands at the default size; small requests get fewer, longer ones.
    n_strands = int(np.clip(vertices // 16, 1, 32))
    nx = min(8, n_strands)
    per = max(8, vertices // n_strands)
    pins = np.stack(np.meshgrid(np.arange(nx) * 0.3, np.arange(-(-n_strands // nx)) * 0.3,
                                indexing="ij"), -1).reshape(-1, 2)[:n_strands]
    pins = np.column_stack([pins - pins.mean(0), np.full(n_strands, 1.0)])
    length = rng.uniform(0.35, 0.55, n_strands)
    amp = rng.uniform(0.04, 0.07, n_strands)
    azim = rng.uniform(0, 2 * np.pi, n_strands)
    ecc = rng.uniform(-0.6, 0.6, n_strands)
    x, v = _hanging_chains(pins, length, per, amp, azim, ecc)
    starts, counts = np.arange(n_strands) * per, np.full(n_strands, per)
    mass = np.full(len(x), 0.02 / per)
    sim = Solver(x, mass, chain_constraints(starts, counts, stretch=2e-7, bend=2e-5),
                 drag=1.0)
    sim.v[:] = v
    top = starts.copy()
    base = x[top].copy()

    def pin_fn(t):
        w = 2 * np.pi * 0.7
        return base + 0.01 * np.array([np.sin(w * t), 1 - np.cos(w * t), 0.0])

    sim.pin(top, pin_fn)
    dt = 1.0 / 120.0
    X = sim.run(frames, dt, substeps=8, iters=12)
    edges = chain_edges(starts, counts)
    h = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1).min()
    return X, {"edges": edges}, {
        "dt": dt, "thickness": 0.25 * h,
        "description": f"rods: {n_strands} pinned strands x {per} vertices swinging "
                       f"on ellipses (first hanging-chain mode), pin plate circling, XPBD, {1/dt:.0f} Hz"}


def cloth(vertices=2304, frames=48, seed=0):
    """A square sheet hanging from two pinned corners, draping as one pin moves.

    0.8 m x 0.8 m, XPBD stretch/shear/bending springs, air drag. The sheet
    first settles (not recorded) from a flat vertical start with a small
    ripple; during the recording the right pin glides 0.2 m toward the left
    one and 0.1 m forward (smooth ramp), so the sheet swings and folds.
    """
    rng = np.random.default_rng(seed)
    n = max(8, int(round(np.sqrt(vertices))))
    size = 0.8
    u, w = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n), indexing="ij")
    u, w = u.ravel(), w.ravel()
    ph = rng.uniform(0, 2 * np.pi, 2)
    # The ripple breaks the symmetry so the sheet does not stay planar.
    ripple = 0.006 * np.sin(7 * u + ph[0]) * np.sin(5 * w + ph[1])
    x = np.column_stack([u - size / 2, ripple, w + 0.2])
    faces = grid_faces(n, n)
    mass = np.full(n * n, 0.15 / (n * n))
    sim = Solver(x, mass, grid_constraints(n, n, stretch=1e-8, shear=1e-6, bend=1e-4),
                 drag=3.0)
    corners = np.array([n - 1, n * n - 1])  # top-left and top-right (w = size)
    base = x[corners].copy()
    dt = 1.0 / 120.0
    settle = 1.0
    t_move = 1.25 * frames * dt

    def pin_fn(t):
        r = np.clip((t - settle) / t_move, 0.0, 1.0)
        ramp = r * r * (3 - 2 * r)
        out = base.copy()
        out[1] += ramp * np.array([-0.16, 0.06, 0.0])
        return out

    sim.pin(corners, pin_fn)
    sim.settle(settle, dt, substeps=8, iters=12)
    sim.drag = 1.0
    X = sim.run(frames, dt, substeps=8, iters=12, t0=settle)
    h = size / (n - 1)
    return X, {"faces": faces}, {
        "dt": dt, "thickness": 0.25 * h,
        "description": f"cloth: {n}x{n} sheet hanging from two pinned corners, one pin "
                       f"gliding inward and forward, XPBD, {1/dt:.0f} Hz"}


def _smoothstep(r):
    r = np.clip(r, 0.0, 1.0)
    return r * r * (3 - 2 * r)


def _held_strip(vertices, seed, motion):
    """The 0.6 m x 0.1 m strip of the twisting scenes, held along both short edges.

    About a 6:1 vertex grid with a small seeded ripple, XPBD stretch/shear/bending
    springs, air drag 3 (for settling). ``motion(t) -> (angle, pull)`` drives the
    right end: turned by `angle` (rad) about the long axis and moved by `pull` (m)
    along it; the left end stays. Returns ``(sim, faces, nx, ny, h)`` with `h` the
    smallest rest edge.
    """
    rng = np.random.default_rng(seed)
    ny = max(4, int(round(np.sqrt(vertices / 6.0))))
    nx = max(8, vertices // ny)
    length, width = 0.6, 0.1
    u, w = np.meshgrid(np.linspace(0, length, nx), np.linspace(-width / 2, width / 2, ny),
                       indexing="ij")
    u, w = u.ravel(), w.ravel()
    ph = rng.uniform(0, 2 * np.pi)
    ripple = 0.002 * np.sin(np.pi * u / length) * np.sin(9 * u + ph)
    x = np.column_stack([u - length / 2, w, 0.5 + ripple])
    faces = grid_faces(nx, ny)
    mass = np.full(nx * ny, 0.05 / (nx * ny))
    sim = Solver(x, mass, grid_constraints(nx, ny, stretch=5e-8, shear=1e-6, bend=1e-4),
                 drag=3.0)
    ends = np.concatenate([np.arange(ny), np.arange((nx - 1) * ny, nx * ny)])
    base = x[ends].copy()
    axis = np.array([1.0, 0.0, 0.0])
    center = np.array([0.0, 0.0, 0.5])

    def pin_fn(t):
        angle, pull = motion(t)
        out = base.copy()
        turned = _rotate(base[ny:] - center, axis, np.full(ny, angle))
        out[ny:] = center + turned + np.array([pull, 0, 0])
        return out

    sim.pin(ends, pin_fn)
    return sim, faces, nx, ny, min(length / (nx - 1), width / (ny - 1))


def twisting_cloth(vertices=1600, frames=60, seed=0):
    """A cloth strip held at both ends, one end turning about the long axis.

    0.6 m x 0.1 m strip (about 6:1 vertex grid) held along both short
    edges; after settling into its gravity sag (not recorded) the right end
    turns by up to 150 degrees about the strip's long axis on a smooth ramp
    and is pulled out by 4 % (stretch), the cloth-twist benchmark kept below
    the twist at which the strip would touch itself.
    """
    dt = 1.0 / 120.0
    settle, t_turn = 0.6, 1.25 * frames * dt

    def motion(t):
        r = _smoothstep((t - settle) / t_turn)
        return np.radians(150.0) * r, 0.04 * 0.6 * r  # pulled out 4 % of the length

    sim, faces, nx, ny, h = _held_strip(vertices, seed, motion)
    sim.settle(settle, dt, substeps=8, iters=12)
    sim.drag = 0.5
    X = sim.run(frames, dt, substeps=8, iters=12, t0=settle)
    return X, {"faces": faces}, {
        "dt": dt, "thickness": 0.25 * h,
        "description": f"twisting-cloth: {nx}x{ny} strip held at both ends, one end "
                       f"turning about the long axis, XPBD, {1/dt:.0f} Hz"}


def cables(vertices=1280, frames=60, seed=0):
    """Separate hanging cables whose anchors move independently (multi-object).

    8 cables (0.8-1.1 m) hang from anchors 0.45 m apart, start swinging in
    the first hanging-chain mode in their own direction, and each anchor
    sways along its own horizontal direction with its own amplitude (4-7 cm),
    frequency and phase, so the cables swing with different phases and
    directions: one affine map for the scene fits poorly, one per cable
    (``components``) fits better.
    """
    rng = np.random.default_rng(seed)
    n_cables, nx = 8, 4
    per = max(8, vertices // n_cables)
    anchors = np.stack(np.meshgrid(np.arange(nx) * 0.45, np.arange(n_cables // nx) * 0.45,
                                   indexing="ij"), -1).reshape(-1, 2)
    anchors = np.column_stack([anchors - anchors.mean(0), np.full(n_cables, 1.5)])
    length = rng.uniform(0.8, 1.1, n_cables)
    x, v = _hanging_chains(anchors, length, per, rng.uniform(0.03, 0.06, n_cables),
                           rng.uniform(0, 2 * np.pi, n_cables), rng.uniform(-0.5, 0.5, n_cables))
    comp = np.repeat(np.arange(n_cables), per)
    starts, counts = np.arange(n_cables) * per, np.full(n_cables, per)
    mass = np.full(len(x), 0.05 / per)
    sim = Solver(x, mass, chain_constraints(starts, counts, stretch=2e-7, bend=2e-5), drag=0.5)
    sim.v[:] = v
    top = starts.copy()
    base = x[top].copy()
    dirs = rng.uniform(0, 2 * np.pi, n_cables)
    amp = rng.uniform(0.04, 0.07, n_cables)
    freq = rng.uniform(0.5, 1.0, n_cables)
    phase = rng.uniform(0, 2 * np.pi, n_cables)
    dvec = np.column_stack([np.cos(dirs), np.sin(dirs), np.zeros(n_cables)])

    def pin_fn(t):
        # Starts at rest offset 0 and ramps in, so the anchors do not jerk.
        ramp = _smoothstep(t / 0.25)
        off = amp * (np.sin(2 * np.pi * freq * t + phase) - np.sin(phase))
        return base + (ramp * off)[:, None] * dvec

    sim.pin(top, pin_fn)
    dt = 1.0 / 120.0
    X = sim.run(frames, dt, substeps=8, iters=12)
    edges = chain_edges(starts, counts)
    h = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1).min()
    return X, {"edges": edges, "components": comp}, {
        "dt": dt, "thickness": 0.25 * h,
        "description": f"cables: {n_cables} separate cables x {per} vertices hanging from "
                       f"independently swaying anchors, XPBD, {1/dt:.0f} Hz"}


def twisted_cables(vertices=1020, frames=60, seed=0):
    """Cables held at both ends whose top ring turns, so they wrap into a rope (self-contact).

    6 cables 0.8 m long hang between two rings of radius 2.5 cm, 0.75 m apart
    (slack 7 %), with a small random sideways velocity each. The top ring turns
    about the vertical axis at up to 1.2 turns/s (smooth start); the cables
    swing, wrap around each other and press together. Contact: edge-edge
    repulsion to half an edge length with friction, every substep truncated
    to the OGC bounds (``pbd.Solver.self_contact``). Recording starts after
    0.35 s (about a quarter turn), when the cables first touch.
    """
    rng = np.random.default_rng(seed)
    n_cables = 6
    per = max(8, vertices // n_cables)
    length, ring, top, bottom = 0.8, 0.025, 1.0, 0.25
    ang = 2 * np.pi * (np.arange(n_cables) + rng.uniform(-0.1, 0.1, n_cables)) / n_cables
    xs, vs = [], []
    s = np.linspace(0.0, 1.0, per)
    sag = np.sqrt(max(length ** 2 - (top - bottom) ** 2, 0.0)) / 2
    for k in range(n_cables):
        end = ring * np.array([np.cos(ang[k]), np.sin(ang[k]), 0.0])
        bow = rng.uniform(0, 2 * np.pi)
        side = np.array([np.cos(bow), np.sin(bow), 0.0])
        # A bowed start so the cable has its rest length; lateral shape sin(pi s).
        line = end + np.outer(1 - s, [0, 0, top]) + np.outer(s, [0, 0, bottom])
        xs.append(line + np.outer(np.sin(np.pi * s), side) * sag)
        vs.append(np.outer(np.sin(np.pi * s), rng.normal(0, 0.05, 3)))
    x = np.concatenate(xs)
    starts, counts = np.arange(n_cables) * per, np.full(n_cables, per)
    edges = chain_edges(starts, counts)
    mass = np.full(len(x), 0.04 / per)
    sim = Solver(x, mass, chain_constraints(starts, counts, stretch=2e-7, bend=2e-5), drag=1.0)
    sim.v[:] = np.concatenate(vs)
    h = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1).min()
    thickness = 0.25 * h
    sim.self_contact(radius=0.5 * h, thickness=thickness, edges=edges, friction=0.3)
    ends = np.concatenate([starts, starts + per - 1])
    base = x[ends].copy()
    turn = np.zeros(2 * n_cables, bool)
    turn[:n_cables] = True
    rate, t_pre = 1.2, 0.35

    def pin_fn(t):
        # angle = 2 pi rate (t - tau (1 - exp(-t / tau))): starts at rest, reaches `rate`.
        a = 2 * np.pi * rate * (t - 0.15 * (1 - np.exp(-t / 0.15)))
        out = base.copy()
        out[turn] = _rotate(base[turn], np.array([0.0, 0.0, 1.0]), np.full(n_cables, a))
        return out

    sim.pin(ends, pin_fn)
    dt = 1.0 / 120.0
    sim.settle(t_pre, dt, substeps=8, iters=12)
    X = sim.run(frames, dt, substeps=8, iters=12, t0=t_pre)
    comp = np.repeat(np.arange(n_cables), per)
    return X, {"edges": edges, "components": comp}, {
        "dt": dt, "thickness": thickness, "contact_radius": 0.5 * h,
        "description": f"twisted-cables: {n_cables} cables x {per} vertices held at both ends, "
                       f"top ring turning, wrapping into a rope with self-contact (OGC-truncated "
                       f"XPBD), {1/dt:.0f} Hz"}


def twisting_cloth_contact(vertices=1600, frames=48, seed=0):
    """The twisting strip turned on past the point where it wrinkles and touches itself.

    The strip of `twisting_cloth` (0.6 m x 0.1 m, held along both short edges,
    settled into its sag) is turned by up to 540 degrees about its long axis while
    the ends are drawn 10 % together, with a linear ramp over the run; self-contact
    on (contact radius half an edge, friction 0.3, OGC truncation). Recording starts
    0.45 s into the turn (about 230 degrees), as the first wrinkles fold over;
    contacts then spread along the strip.
    """
    dt = 1.0 / 120.0
    settle, t_pre = 0.6, 0.45
    t_turn = t_pre + frames * dt

    def motion(t):
        r = np.clip((t - settle) / t_turn, 0.0, 1.0)
        return np.radians(540.0) * r, -0.1 * 0.6 * r  # drawn in 10 % of the length

    sim, faces, nx, ny, h = _held_strip(vertices, seed, motion)
    thickness = 0.25 * h
    sim.settle(settle, dt, substeps=8, iters=12)
    sim.self_contact(radius=0.5 * h, thickness=thickness, faces=faces, friction=0.3)
    sim.drag = 0.5
    sim.run(int(round(t_pre / dt)) + 1, dt, substeps=8, iters=20, t0=settle)
    X = sim.run(frames, dt, substeps=8, iters=20, t0=settle + t_pre)
    return X, {"faces": faces}, {
        "dt": dt, "thickness": thickness, "contact_radius": 0.5 * h,
        "description": f"twisting-cloth-contact: {nx}x{ny} strip held at both ends, one end "
                       f"turning to 540 degrees with the ends drawn together, self-contact "
                       f"(OGC-truncated XPBD), {1/dt:.0f} Hz"}


def box_mesh(lo, hi):
    """Vertices (8, 3) and outward triangles (12, 3) of the axis-aligned box [lo, hi]."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    V = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int64)
    return V, F


def ground_square(half):
    """The ground z = 0 as a solver sees it, a square of side 2 `half` (4 vertices, 2
    triangles facing up; pinned inside the OGC contact, so the cloth keeps the thickness
    from it), and as a file records it (`GROUND`, the half-space z > 0)."""
    V = np.array([[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]])
    return V, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


#: The recorded form of `ground_square`: obstacles/ground, normal (0, 0, 1), offset 0.
GROUND = {"normal": np.array([0.0, 0.0, 1.0]), "offset": 0.0}


def cloth_drape_box(vertices=900, frames=60, seed=0):
    """A square sheet dropped onto a box, draping over its edges onto the ground.

    1.2 m x 1.2 m sheet (slightly turned and off-centre, small seeded ripple) falls
    from 0.15 m above a 0.5 m x 0.5 m x 0.35 m box standing on the ground z = 0; it
    lands on the box top, folds over the edges and its corners reach the ground.
    The box and a 4 m ground square are simulated as pinned triangles inside the OGC
    self-contact (contact radius half an edge, thickness a quarter edge, friction
    0.3, OGC truncation), so the recorded cloth keeps the thickness from both; the
    file stores them as obstacles: ``box`` (vertices + faces) and ``ground`` (a
    half-space, normal (0, 0, 1), offset 0). Recording starts just before impact.
    """
    rng = np.random.default_rng(seed)
    n = max(8, int(round(np.sqrt(vertices))))
    size = 1.2
    u, w = np.meshgrid(np.linspace(-size / 2, size / 2, n), np.linspace(-size / 2, size / 2, n), indexing="ij")
    u, w = u.ravel(), w.ravel()
    turn = np.radians(20.0)
    ph = rng.uniform(0, 2 * np.pi, 2)
    ripple = 0.004 * np.sin(5 * u + ph[0]) * np.sin(4 * w + ph[1])
    cloth = np.column_stack([np.cos(turn) * u - np.sin(turn) * w + 0.05,
                             np.sin(turn) * u + np.cos(turn) * w + 0.03, 0.5 + ripple])
    box_v, box_f = box_mesh([-0.25, -0.25, 0.0], [0.25, 0.25, 0.35])
    ground_v, ground_f = ground_square(2.0)
    nc = n * n
    x = np.concatenate([cloth, box_v, ground_v])
    faces = grid_faces(n, n)
    all_faces = np.concatenate([faces, box_f + nc, ground_f + nc + 8])
    mass = np.full(len(x), 0.3 / nc)
    sim = Solver(x, mass, grid_constraints(n, n, stretch=1e-8, shear=1e-6, bend=1e-4), drag=1.0)
    fixed = np.arange(nc, len(x))
    sim.pin(fixed, lambda t: x[fixed])
    h = size / (n - 1)
    thickness, radius = 0.25 * h, 0.5 * h
    sim.self_contact(radius=radius, thickness=thickness, faces=all_faces, friction=0.3)
    dt = 1.0 / 60.0
    t_pre = 0.12
    sim.settle(t_pre, dt, substeps=8, iters=12)
    X = sim.run(frames, dt, substeps=8, iters=12, t0=t_pre)[:, :nc]
    obstacles = {"box": {"vertices": box_v, "faces": box_f},
                 "ground": GROUND}
    return X, {"faces": faces, "obstacles": obstacles}, {
        "dt": dt, "thickness": thickness, "contact_radius": radius,
        "description": f"cloth-drape-box: {n}x{n} sheet dropped onto a box on the ground, draping "
                       f"over its edges (box and ground in the OGC contact, OGC-truncated XPBD), "
                       f"{1/dt:.0f} Hz"}
# --- fast coherent motion with tight self-contact (issue 12) -------------------


def _layer_stack(n, layers, size, gap, z0):
    """`layers` square n x n grids (side `size`) stacked `gap` apart from height `z0` up."""
    u, w = np.meshgrid(np.linspace(-size / 2, size / 2, n), np.linspace(-size / 2, size / 2, n), indexing="ij")
    xs, faces, cons = [], [], []
    for k in range(layers):
        xs.append(np.column_stack([u.ravel(), w.ravel(), np.full(n * n, z0 + k * gap)]))
        faces.append(grid_faces(n, n) + k * n * n)
        for ij, a in grid_constraints(n, n, stretch=1e-8, shear=1e-6, bend=1e-5):
            cons.append((ij + k * n * n, a))
    comp = np.repeat(np.arange(layers), n * n)
    return np.concatenate(xs), np.concatenate(faces), cons, comp


def falling_stack(vertices=768, frames=40, seed=0):
    """A stack of cloth layers a few contact radii apart, falling freely, then landing.

    3 square layers (0.4 m, about ``vertices / 3`` vertices each) lie flat 1.5 edge
    lengths (3 contact radii) apart, with a small seeded ripple, and start falling
    at 1.5 m/s from 0.2 m above the ground z = 0. They fall as one (the same free
    fall for every vertex: coherent motion) and land about half-way through the
    recording, when the layers pile up on each other (self-contact, contact radius
    half an edge, OGC-truncated XPBD). The ground (a 2 m square) is simulated as two
    pinned triangles inside the OGC contact, so the cloth keeps the thickness from it,
    and the file stores it as the half-space ``ground`` (normal (0, 0, 1), offset 0),
    as `cloth_drape_box` does.
    """
    rng = np.random.default_rng(seed)
    layers = 3
    n = max(6, int(round(np.sqrt(vertices / layers))))
    size = 0.4
    h = size / (n - 1)
    x, faces, cons, comp = _layer_stack(n, layers, size, 1.5 * h, 0.2)
    x[:, 2] += 0.002 * np.sin(9 * x[:, 0] + rng.uniform(0, 6.3)) * np.sin(7 * x[:, 1] + rng.uniform(0, 6.3))
    nc = len(x)
    ground_v, ground_f = ground_square(1.0)
    xa = np.concatenate([x, ground_v])
    mass = np.full(len(xa), 0.05 / (n * n))
    sim = Solver(xa, mass, cons, drag=0.1)
    sim.v[:nc, 2] = -1.5
    fixed = np.arange(nc, len(xa))
    sim.pin(fixed, lambda t: xa[fixed])
    thickness = 0.25 * h
    sim.self_contact(radius=0.5 * h, thickness=thickness, faces=np.concatenate([faces, ground_f + nc]), friction=0.3)
    dt = 1.0 / 120.0
    X = sim.run(frames, dt, substeps=8, iters=12)[:, :nc]
    return X, {"faces": faces, "components": comp, "obstacles": {"ground": GROUND}}, {
        "dt": dt, "thickness": thickness, "contact_radius": 0.5 * h,
        "description": f"falling-stack: {layers} cloth layers {n}x{n}, 3 contact radii apart, falling "
                       f"at 1.5 m/s and landing on the ground, self-contact (OGC-truncated XPBD), "
                       f"{1/dt:.0f} Hz"}


def carried_stack(vertices=768, frames=40, seed=0):
    """A stack of cloth layers carried quickly around a circle by its held corners.

    3 square layers (0.4 m) 3 contact radii apart, every layer held at its four
    corners; the corners move together around a horizontal circle of radius
    0.15 m at 1.5 turns/s (smooth start during an unrecorded lead-in) while
    rising and falling 3 cm: the whole stack is carried coherently, sagging and
    swinging, the layers pressing on each other where they sag (self-contact).
    """
    rng = np.random.default_rng(seed)
    layers = 3
    n = max(6, int(round(np.sqrt(vertices / layers))))
    size = 0.4
    h = size / (n - 1)
    x, faces, cons, comp = _layer_stack(n, layers, size, 1.5 * h, 0.5)
    x[:, 2] += 0.001 * np.sin(11 * x[:, 0] + rng.uniform(0, 6.3)) * np.sin(5 * x[:, 1] + rng.uniform(0, 6.3))
    mass = np.full(len(x), 0.05 / (n * n))
    sim = Solver(x, mass, cons, drag=1.0)
    corners = np.concatenate([np.array([0, n - 1, n * (n - 1), n * n - 1]) + k * n * n for k in range(layers)])
    base = x[corners].copy()
    thickness = 0.25 * h
    sim.self_contact(radius=0.5 * h, thickness=thickness, faces=faces, friction=0.3)
    rate, rad, t_pre = 1.5, 0.15, 0.3

    def pin_fn(t):
        a = 2 * np.pi * rate * (t - 0.2 * (1 - np.exp(-t / 0.2)))
        off = np.array([rad * (np.cos(a) - 1.0), rad * np.sin(a), 0.03 * np.sin(a)])
        return base + off

    sim.pin(corners, pin_fn)
    dt = 1.0 / 120.0
    sim.settle(t_pre, dt, substeps=8, iters=12)
    X = sim.run(frames, dt, substeps=8, iters=12, t0=t_pre)
    return X, {"faces": faces, "components": comp}, {
        "dt": dt, "thickness": thickness, "contact_radius": 0.5 * h,
        "description": f"carried-stack: {layers} cloth layers {n}x{n} held at their corners, carried "
                       f"around a 0.15 m circle at {rate} turns/s, self-contact (OGC-truncated XPBD), "
                       f"{1/dt:.0f} Hz"}


def swinging_coil(vertices=600, frames=40, seed=0):
    """A coiled cable (a helix of touching turns) swinging from its held top end.

    One cable coiled into a helix of radius 5 cm with a pitch of 3 contact radii
    (turns nearly touching), stiff in bending (springs over 2, 3, 5 and 9 segments)
    so that it keeps its coil, held along a quarter of its first turn, which swings
    on an arc of 0.12 m at 1 Hz: the coil swings as a body (coherent rotation and
    translation), its turns pressing together where it lags (self-contact, contact
    radius half an edge).
    """
    rng = np.random.default_rng(seed)
    per = max(40, int(vertices))
    turns = 6.0
    radius = 0.05
    ang = np.linspace(0, 2 * np.pi * turns, per)
    h = np.hypot(2 * np.pi * radius * turns / (per - 1), 0.0)
    pitch = 3 * 0.5 * h
    x = np.column_stack([radius * np.cos(ang), radius * np.sin(ang), 0.8 - pitch * ang / (2 * np.pi)])
    x[:, :2] += rng.normal(0, 1e-4, (per, 2))
    edges = chain_edges(np.array([0]), np.array([per]))
    h = np.linalg.norm(x[1:] - x[:-1], axis=1).min()
    mass = np.full(per, 0.05 / per)
    # Bending springs over 2, 3 and 5 segments keep the helix's shape.
    cons = list(chain_constraints(np.array([0]), np.array([per]), stretch=1e-9, bend=1e-9))
    for k in (3, 5, 9):
        i = np.arange(per - k)
        cons.append((np.column_stack([i, i + k]).astype(np.int64), 1e-9))
    sim = Solver(x, mass, cons, drag=0.5)
    thickness = 0.25 * h
    sim.self_contact(radius=0.5 * h, thickness=thickness, edges=edges, friction=0.3)
    top = np.arange(per // int(turns) // 4)  # a quarter of the first turn is held
    base = x[top].copy()
    freq, amp, t_pre = 1.0, 0.12, 0.2

    def pin_fn(t):
        r = _smoothstep(t / 0.3)
        a = amp * r * np.sin(2 * np.pi * freq * t)
        return base + np.array([a, 0.0, 0.1 * a * a])

    sim.pin(top, pin_fn)
    dt = 1.0 / 120.0
    # 16 substeps: the OGC truncation of every substep (bound 0.45 (2 r - thickness))
    # then stays well above the swing's per-substep motion, so it never jerks the coil.
    sim.settle(t_pre, dt, substeps=16, iters=12)
    X = sim.run(frames, dt, substeps=16, iters=12, t0=t_pre)
    return X, {"edges": edges}, {
        "dt": dt, "thickness": thickness, "contact_radius": 0.5 * h,
        "description": f"swinging-coil: one cable of {per} vertices coiled into {turns:g} turns 3 contact "
                       f"radii apart, held at the top and swung at {freq} Hz, self-contact "
                       f"(OGC-truncated XPBD), {1/dt:.0f} Hz"}
