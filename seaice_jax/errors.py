"""Exceptions raised by seaice_jax, and the exit codes of the ``seaice`` command.

Every error names what is at fault (file, line, point id, parameter or array index), so that a researcher can
find the bad input without reading the code.

Exit codes (:func:`exit_code`, one table for every command):

* :data:`EXIT_OK` (0): the command did what was asked.
* :data:`EXIT_FAILURE` (1): a runtime failure on valid input: a computation that failed
  (:class:`ComputationError`, e.g. an adjustment that did not converge), an output that could not be written
  (permissions, a full disk), or an unexpected error.
* :data:`EXIT_USAGE` (2): usage or bad input: an unknown option or a value out of range (argparse), an input file
  that is missing or malformed, observations that cannot determine the unknowns (:class:`SeaiceError` and the
  ``ValueError`` of a bad argument).
* 130 / 143: interrupted by SIGINT (Ctrl-C) / SIGTERM (128 + the signal's number), nothing partial left.
"""

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2


class SeaiceError(ValueError):
    """Base class of all seaice_jax input and geometry errors (a ``ValueError``)."""


class ComputationError(SeaiceError):
    """The input was valid but the computation failed, e.g. an adjustment that did not converge (exit code 1)."""


class NotConvergedError(ComputationError):
    """An adjustment that stopped before its convergence test was met (at its step limit, or at a point where the
    square sum is not finite); the message names the steps, σ̂0 and the unknown the last step moved most.

    Attributes:
        steps: the iterations taken.
    """

    def __init__(self, message: str, steps: int):
        super().__init__(message)
        self.steps = steps


class GeometryError(SeaiceError):
    """Impossible geometry, e.g. a slant range with no intersection with the Earth's surface.

    Attributes:
        indices: tuple of index arrays (as from ``numpy.nonzero``) of the offending elements.
    """

    def __init__(self, message: str, indices=()):
        super().__init__(message)
        self.indices = indices


class RankDeficiencyError(SeaiceError):
    """The observations cannot determine some parameters (a datum defect, too few or badly placed points).

    Attributes:
        parameters: names of the parameters involved in the undetermined combinations.
    """

    def __init__(self, message: str, parameters=()):
        super().__init__(message)
        self.parameters = tuple(parameters)


_MISSING_PATH = (FileNotFoundError, IsADirectoryError, NotADirectoryError)


def exit_code(error: BaseException) -> int:
    """The ``seaice`` exit code of a command stopped by ``error`` (see the module docstring): :data:`EXIT_FAILURE`
    for a :class:`ComputationError`, an ``OSError`` other than a path that does not exist or is of the wrong kind,
    and anything unexpected; :data:`EXIT_USAGE` for the other ``ValueError`` s (every :class:`SeaiceError`) and a
    missing path."""
    if isinstance(error, ComputationError):
        return EXIT_FAILURE
    if isinstance(error, (ValueError, *_MISSING_PATH)):
        return EXIT_USAGE
    return EXIT_FAILURE
