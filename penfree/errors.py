"""Exception hierarchy. The CLI maps `InputError` (and subclasses) to exit 2."""


class PenfreeError(Exception):
    """Base class of every error penfree raises on purpose."""


class InputError(PenfreeError, ValueError):
    """Unusable input or arguments: a file, dataset or value is not what was expected.

    Messages are one line and name the file, the dataset and the expectation,
    e.g. ``positions must be (T, N, 3); got (10, 4) in frames.h5:/positions``.
    """


class FormatError(InputError):
    """A file cannot be read as the format it claims (not HDF5, truncated, bad layout)."""


class OutputExistsError(InputError):
    """The output exists and ``overwrite`` was not given."""


class CertificateError(PenfreeError):
    """A map about to be written failed the exact certificate (an internal bug, never user input)."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C (SIGINT) or SIGTERM; the CLI exits 128 + `signum` (130 / 143) after cleaning up."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)
