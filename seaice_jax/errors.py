"""Exceptions raised by seaice_jax.

Every error names what is at fault (file, line, point id, parameter or array index), so that a researcher can
find the bad input without reading the code.
"""


class SeaiceError(ValueError):
    """Base class of all seaice_jax input and geometry errors (a ``ValueError``)."""


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
