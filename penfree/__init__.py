"""penfree: certified penetration-free affine pre-deformation for simulation frames.

The public API (SPEC section 10) is importable from here. Names are resolved
lazily so that ``import penfree`` stays cheap (no Numba compilation).

>>> import penfree
>>> seq = penfree.read_sequence("samples/rods.h5")      # doctest: +SKIP
>>> r = penfree.fit_step(seq.positions[0], seq.positions[1])  # doctest: +SKIP
>>> penfree.certify(r.A, margin=0.0)                    # doctest: +SKIP
True
"""

from ._version import __version__
from .errors import CertificateError, FormatError, InputError, OutputExistsError, PenfreeError
from .sequence import Obstacle, Sequence

_LAZY = {
    "read_sequence": ("penfree.formats", "read_sequence"),
    "write_sequence": ("penfree.formats", "write_sequence"),
    "fit_step": ("penfree.core.fit.step", "fit_step"),
    "StepResult": ("penfree.core.fit.step", "StepResult"),
    "certify": ("penfree.core.fit.certificate", "certify"),
    "ccd_edge_edge": ("penfree.core.contact.ccd", "ccd_edge_edge"),
    "ccd_vertex_face": ("penfree.core.contact.ccd", "ccd_vertex_face"),
    "verify_step": ("penfree.core.verify.path", "verify_step"),
    "trust_region_bounds": ("penfree.core.trust.bounds", "trust_region_bounds"),
    "NeighbourList": ("penfree.core.contact.neighbours", "NeighbourList"),
    "predeform": ("penfree.core.pipeline.predeform", "predeform"),
    "client_replay_step": ("penfree.core.trust.client", "replay_step"),
    "client_counts": ("penfree.core.trust.client_stats", "client_counts"),
}

__all__ = [
    "__version__",
    "PenfreeError",
    "InputError",
    "FormatError",
    "OutputExistsError",
    "CertificateError",
    "Sequence",
    "Obstacle",
    *_LAZY,
]


def __getattr__(name):
    if name in _LAZY:
        import importlib

        mod, attr = _LAZY[name]
        value = getattr(importlib.import_module(mod), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'penfree' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
