"""The error every estimator reader raises (its own module: the readers and :mod:`.smplx_shape` share it)."""


class EstimateFormatError(ValueError):
    """An estimator output file does not have the layout its reader expects (the message names the key)."""
