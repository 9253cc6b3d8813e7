"""Named tolerances and defaults, in one place, each with where its value comes from.

Modules import from here; no other module defines a tolerance literal.
"""

# --- data model (SPEC section 2) ---------------------------------------------
#: HDF5 layout version written to and accepted from ``penfree_format``.
FORMAT_VERSION = 1

# --- fit (SPEC section 4) ----------------------------------------------------
#: Number of fixed chunks for deterministic parallel reductions; results must
#: not depend on the thread count, so the chunking does not either.
REDUCTION_CHUNKS = 64

#: Floor of the relative eigenvalue cut-off of the pseudo-inverse of the
#: covariance C: below ~1e3 * machine epsilon an eigenvalue cannot be told
#: apart from rounding in a float64 sum of N products.
PINV_RTOL_FLOOR = 1e-12

#: ``auto`` model: the cheapest model whose residual (weighted RMS to x_pred)
#: is within this relative tolerance of the best model's residual.
AUTO_MODEL_RTOL = 0.05

MODELS = ("translation", "rigid", "similarity", "affine")
PROJECTIONS = ("none", "svd", "sym", "auto")

#: Noise-aware rank cut-off of the fit (penfree.core.fit.models.significant_subspace):
#: a direction of C is kept only if the standard error of the slope D e it
#: carries is at most this (dimensionless strain per step). Real per-step
#: strains are ~1e-3..1e-2 and a slope error of 1e-2 moves sigma_min(I + tD)
#: by at most 1e-2, far from the certificate's limit; noise-driven slopes of a
#: near-straight cable are orders of magnitude larger (issue: noise-aware cut-off).
FIT_NOISE_SLOPE_TOL = 1e-2

#: A direction's RMS spread must exceed this many input ulps of the typical
#: coordinate (eps_dtype * |coordinates|): below it the shape is quantisation
#: noise (float32 input precision as a noise floor; ~4 bits of headroom).
FIT_PRECISION_FACTOR = 16.0

#: ``auto`` model: absolute slack, relative to the translation's RMS residual.
#: Residuals from moments cancel at ~sqrt(eps) ~ 1.5e-8 of it; 1e-6 leaves room,
#: so models that are equal up to rounding count as equal.
AUTO_MODEL_ATOL_REL = 1e-6

#: Fit kernels (moments, applying the map, auto's predictor) may run their fixed
#: chunks in parallel from this many vertices on (same chunks, same summation order,
#: so the same bits); below it they run serially. Above it `FIT_BUILD` decides.
#: A parallel region saves a third to a half of a 64K pass on an idle machine, but
#: with a core held by another process it waits for a late thread: mean fit_step at
#: 64K 1-15 ms parallel vs 0.4-0.8 ms serial (benchmarks/bench_contention.py).
PARALLEL_MIN_VERTICES = 1 << 14

#: Which build of the fit kernels runs from `PARALLEL_MIN_VERTICES` on: "adaptive"
#: (`penfree.core.parallel.Pace`: the one that has cost less per vertex lately, stalls
#: included, the other tried now and then), "serial" or "parallel" (forced: the tests' oracles
#: and the benchmarks' columns; "parallel" also below the threshold).
FIT_BUILD = "adaptive"

# --- projection and certificate (SPEC section 5) -----------------------------
#: Upper clamp of singular values in the ``svd`` projection (the original
#: recipe clamps into [margin, S_MAX]); per-frame motion never needs more.
SVD_SMAX = 10.0

#: Fast certificate (penfree.core.fit.certificate.fast_margin_bound): rounding
#: allowance c in  lambda_min >= computed - c * eps * (1 + ||sym D||_F).
#: Covers forming D = A - I and sym(D) (entrywise relative error <= eps/2,
#: Frobenius-bounded), LAPACK's backward error of the 3x3 symmetric
#: eigensolver (a small multiple of eps ||S||_2) and the final additions,
#: with a wide factor of safety.
FAST_CERT_ROUNDING_C = 64.0

#: ``sym`` projection: eigenvalues of sym(D) are clamped at (margin - 1) plus
#: this times (1 + ||sym D||_F), ~70x the fast test's rounding allowance, so
#: the rounded result still passes the fast test.
SYM_SAFETY_REL = 1e-12

#: The margin rule of a thickness (`core.gate.margin_rule`): with h > 0 every map
#: must keep sigma_min(I + tD) above 1 / this factor, which keeps every pair that
#: starts more than this many thicknesses apart at least h apart; the pairs closer
#: than that (one proximity query) go through the conservative CCD. 0.1 barely
#: restricts per-frame motion (rotations up to arccos(0.1) = 84 deg per step).
MARGIN_GAP_RADIUS_FACTOR = 10.0
#: The margin every map `deform` writes is certified with, at thickness 0 too
#: (`core.gate.deform_margin`). Margin 0 proves the guarantee there (a nonsingular path
#: is a bijection), but only in exact arithmetic for a map certified barely: `sym` at
#: margin 0 projects a half-turn onto the boundary, and a rigid fit of two rods, one
#: turning 0.7 rad a step, came out as ``A ~ n n^T`` (sigma_min 4e-12): x_def put the
#: whole scene on a line, every pair of rods within 4e-13 of each other. 0.1, the
#: margin of a positive thickness, keeps every pair at least a tenth of its start
#: distance along the path; real steps certify far above it (the bundled samples at
#: thickness 0, 4 models: one per-component step at 0.034, every other one above 0.28).
DEFORM_MIN_MARGIN = 0.1
#: The stored x_def may differ from the exact A x + b by at most NEAR_SLACK_REL / 2 * h
#: per vertex (checked per candidate), so no near-pair radius exceeds
#: MARGIN_GAP_RADIUS_FACTOR * h * (1 + NEAR_SLACK_REL); or, where storing x_def in its
#: dtype rounds by more (float32 far from the origin), by that rounding, up to h
#: (`gate.StepGate.rounding_limit`: the radius then grows with it, up to 3x).
NEAR_SLACK_REL = 0.01
#: Fractions of the preferred map's step tried when every full candidate fails the
#: safety gate (a prefix of its certified path), before doing nothing.
SHORTEN_LEVELS = (0.5, 0.25, 0.1)
#: First radius of the gate's near-pair query, in thicknesses: a map with
#: sigma_min >= m_c only needs the pairs within (h + 2 delta) / m_c, about 1.0-1.2 h for
#: per-frame motion; the query is redone larger for a map that shrinks more.
NEAR_FIRST_FACTOR = 1.5

# --- verification (SPEC section 6) -------------------------------------------
#: Pairs listed per step by default (``verify --max-pairs``).
DEFAULT_MAX_PAIRS = 10

# --- trust region (SPEC section 7) -------------------------------------------
#: OGC gamma_p, as in the authors' own code.
DEFAULT_GAMMA = 0.45
#: Projected frame time: CD share of the frame and frame time at 64K vertices,
#: from the originating test case.
DEFAULT_CD_SHARE = 0.5
DEFAULT_FRAME_MS = 32.0
#: Cap on replay passes (SPEC section 7).
DEFAULT_REPLAY_CAP = 64
#: K_1pct = ceil of this percentile of r_v (SPEC: "re-detect when >= 1% are truncated").
K_PERCENTILE = 99
#: numpy.percentile method of every r_v quantile (core/trust/stats.py): "higher" returns an
#: observed r_v, and with it ceil(q99) is exactly the smallest pass count after which
#: fewer than 1% of the vertices are still truncated.
PERCENTILE_METHOD = "higher"
#: r_v histograms (core/trust/stats.py): log bins over 10^lo .. 10^hi, this many per decade,
#: plus a bin for r = 0 below and one for r >= 10^hi (and blocked vertices) above.
R_HIST_DECADES = (-4, 4)
R_HIST_BINS_PER_DECADE = 8
#: trust_region_bounds without a query radius (penfree/core/trust/bounds.py):
#: r_q = thickness + this fraction of the bounding-box diagonal of x, a stand-in
#: for the step's largest displacement that only the caller knows (lead's brief).
DEFAULT_RADIUS_FRACTION = 0.1

# --- floating point -----------------------------------------------------------
#: Unit roundoff of float64 (round to nearest), the u of every rounding-error bound.
UNIT_ROUNDOFF = 2.0**-53
#: How far above a pair's true distance its computed one (`contact.distance`) may lie,
#: relative to the coordinates' magnitude. The kernels return the distance of two
#: computed points on the primitives, so it is never much too small, but an
#: ill-conditioned pair (nearly parallel crossing segments, a vertex over a sliver
#: triangle) gets points off the optimum: by about min(L sin a, u L / sin a) <= sqrt(u) L
#: for an angle a (the endpoint and edge candidates hold the first, the solve the
#: second). A computed distance proves a pair apart only above the radius plus this
#: much; 16 sqrt(u) leaves room (an audit found 5e-11 computed for a true 2e-19 between
#: rods of unit scale, and 1.1e-12 for 1.2e-18 over a 1e-6 wide triangle).
DISTANCE_ROUNDING_REL = 16.0 * UNIT_ROUNDOFF ** 0.5

# --- CCD (SPEC sections 6 and 10; penfree/core/contact/ccd.py) ---------------
#: Proven bound of the floating-point error of one corner value of the contact
#: function F, relative to the largest coordinate magnitude M of the query.
#: The worst evaluation chain (x(t) = x0 + t (x1 - x0), then 3 differences, 2
#: products by u, v in [0, 1] and 2 sums) stays below 56 u M, u = 2^-53; 2^-46 = 128 u
#: leaves a factor 2 of slack.
CCD_ERR_REL = 2.0**-46
#: Absolute term covering underflow (each of the ~20 operations loses at most
#: 2^-1075 when results are subnormal).
CCD_ERR_ABS = 1e-300
#: A box whose image under F is narrower than CCD_TOL_REL times the query's extent
#: (and at least 4 times the error bound) and cannot be discarded is reported as
#: a contact: the primitives then are within sqrt(3) (thickness + tol + 2 err)
#: at the reported toi. 1e-10 resolves the 1e-9 near-misses of Wang et al. 2021.
CCD_TOL_REL = 1e-10
#: The reported toi comes from a box at most CCD_TOI_TOL * t_max wide in time.
CCD_TOI_TOL = 1e-6
#: Boxes examined per query before giving up and reporting a (conservative) hit.
CCD_MAX_BOXES = 1 << 15
#: Flagged queries per batch decided by the exact rational path (~1-4 ms each);
#: beyond it they stay flagged (conservative), so a scene in contact everywhere
#: cannot stall `verify` for minutes.
CCD_MAX_EXACT = 5000

#: Coordinates beyond this could overflow in the ~6 M-sized intermediate products
#: of the CCD kernel: such queries are never declared separated.
CCD_MAX_COORD = 1e150

# --- verification (penfree/core/verify/affine.py) -----------------------------
#: Certificate margins tried (largest first) by the affine fast path of `verify` when
#: the field-of-values bound gives none: rotations beyond arccos(m) per step need a
#: smaller m; below 0.01 the start gaps it asks for are too wide to be useful.
VERIFY_MARGIN_LADDER = (0.5, 0.25, 0.1, 0.03, 0.01)

# --- collision-aware model choice (penfree/core/fit/auto.py) -----------------
#: Rounding allowance of sigma_min from LAPACK's SVD: backward error
#: p(3) * eps * ||A||_2 with p(3) a small constant; 64 is a wide factor of safety.
SIGMA_ROUNDING_C = 64.0
#: Predicted bounds are shrunk by this relative amount so that the rounding of the
#: stored x_def (float32 outputs round at ~6e-8 relative) cannot make a prediction
#: exceed the bound recomputed at the deformed state.
PREDICT_SLACK_REL = 1e-6
#: Predicted K of a candidate under which some moving vertex may have no room at all
#: (predicted bound 0 where the start bound is positive): worse than any finite count.
K_UNBOUNDED = 1 << 62
#: Candidates besides the model ladder: the affine map with singular values clamped
#: into [1 - delta, 1 + delta], and the blends I + alpha D_affine.
SELECT_CLAMP_LEVELS = (0.1, 0.03, 0.01, 0.003)
SELECT_BLEND_LEVELS = (0.75, 0.5, 0.25)
#: Among equal predicted K_1pct, a candidate must lower the predicted 99th percentile
#: of r_v by more than this (relative) to beat a simpler one.
SELECT_TIE_RTOL = 0.02
#: ... and by more than this absolute amount: r_v is a ratio of lengths, and a map
#: that reaches the prediction up to rounding has r_v ~ 1e-16, which is no signal.
SELECT_TIE_ATOL = 1e-9

# --- real-client replay (penfree/core/trust/client.py) ------------------------------
#: Iterations after the warm start before a replay stops (each is one filtered
#: step of the solver toward x_next; a converging replay needs a handful).
DEFAULT_CLIENT_MAX_ITER = 32
#: A vertex within this fraction of the step's largest recorded move from x_next
#: has arrived (the iterations land exactly on x_next when not truncated).
DEFAULT_CLIENT_TOL_REL = 1e-6
#: The client updates its trust region (a CD pass) when more than this fraction of the
#: mesh's vertices were truncated (ipctk.ogc.TrustRegion's ``update_threshold``).
CLIENT_UPDATE_THRESHOLD = 0.01
#: `auto` under a client model (penfree/core/client_select.py): candidates replayed
#: per step besides doing nothing, best static prediction first (each replay costs a
#: few bound computations).
CLIENT_SELECT_SHORTLIST = 3
#: Start states whose query results a shared `client.ClientQuery` keeps: a step's
#: replays start from doing nothing and up to `CLIENT_SELECT_SHORTLIST` + 1 candidates,
#: each replayed toward two targets one after the other, so the last 4 states cover
#: every repeat (`client_counts` replays both truncations from the same starts).
CLIENT_QUERY_MEMO = 4
#: Vertices whose start separation is within this many contact radii are in contact:
#: the predictor holds them at x (resting contact lives inside the contact radius).
#: Not more: on a cloth grid a vertex is ~0.7 edges from the triangle across its
#: cell's diagonal, and with the usual radius of half an edge a larger factor would
#: hold every vertex of a free sheet.
CONTACT_HOLD_FACTOR = 1.0
#: ... and only while at rest: a contact vertex whose last step moved it more than this
#: many contact radii is not held. gamma_p (`DEFAULT_GAMMA`) times the contact radius
#: is the largest trust region a vertex in contact can have, so a vertex that moved
#: farther moved with what it touches (a coil's turns swinging together).
CONTACT_REST_STEP = DEFAULT_GAMMA


# --- report (penfree/report) ---------------------------------------------------------
#: Largest mean CD-pass count a baseline report may hold. K is a count of passes (>= 1,
#: SPEC section 7); float64 holds every integer only up to 2^53, beyond which a count is
#: no longer one (no recording comes near it: its trust regions would be 2^53 times
#: smaller than its steps).
BASELINE_K_MAX = 2.0 ** 53
#: Relative difference above which a file's stored stats/ differ from the statistics
#: computed again (the same computation gives the same bits; this only forgives a
#: reordered sum).
STORED_STATS_RTOL = 1e-9
