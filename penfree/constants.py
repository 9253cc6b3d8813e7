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

# --- projection and certificate (SPEC section 5) -----------------------------
#: Upper clamp of singular values in the ``svd`` projection (the original
#: recipe clamps into [margin, S_MAX]); per-frame motion never needs more.
SVD_SMAX = 10.0

#: With a thickness h, the margin is h / d0 (d0 the smallest start gap). d0 is only
#: searched within this many thicknesses: beyond it the margin h / radius (<= 0.1)
#: is already sufficient and barely restricts per-frame motion (arccos(0.1) = 84 deg).
MARGIN_GAP_RADIUS_FACTOR = 10.0

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
