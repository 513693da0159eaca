"""Checks shared by every public entry point, and the flags every result carries.

- :mod:`~anra_torch.checks.inputs`: one place for each kind of input check and its one-line message
  (``ValueError`` for a bad value or shape, ``TypeError`` for a wrong type);
- :mod:`~anra_torch.checks.flags`: plausibility and model-failure flags, the warnings a result carries,
  worded once for every command;
- :mod:`~anra_torch.checks.outputs`: where outputs go: never over an input, written atomically.
"""

from anra_torch.checks.flags import (
    DEPTH_BIAS,
    MIN_RELIABILITY,
    MIN_SIGNIFICANCE,
    MODEL_FAILURE_RATIO,
    PLAUSIBLE_DIFFUSIVITY,
    POOR_FIT,
    depth_bias,
    diffusivity_warnings,
    extended_diffusivity_warning,
    implausible_diffusivity,
    model_failure,
    poor_fit,
    verdicts,
)
from anra_torch.checks.inputs import (
    MAX_NON_FINITE,
    SPACING_RANGE,
    VALUE_LIMIT,
    as_fields,
    as_spacing,
    as_video,
    check_choice,
    check_dtype,
    check_int,
    check_shape,
    in_range_values,
    join_messages,
    mostly_finite,
    number,
    one_line,
    own_tensor,
    positive,
    spacing_in_range,
    uniform_step,
)
from anra_torch.checks.outputs import atomic_output, check_output, write_text

__all__ = [
    "DEPTH_BIAS",
    "MAX_NON_FINITE",
    "MIN_RELIABILITY",
    "MIN_SIGNIFICANCE",
    "MODEL_FAILURE_RATIO",
    "PLAUSIBLE_DIFFUSIVITY",
    "POOR_FIT",
    "SPACING_RANGE",
    "VALUE_LIMIT",
    "as_fields",
    "as_spacing",
    "as_video",
    "atomic_output",
    "check_choice",
    "check_dtype",
    "check_int",
    "check_output",
    "check_shape",
    "depth_bias",
    "diffusivity_warnings",
    "extended_diffusivity_warning",
    "implausible_diffusivity",
    "in_range_values",
    "join_messages",
    "model_failure",
    "mostly_finite",
    "number",
    "one_line",
    "own_tensor",
    "poor_fit",
    "positive",
    "spacing_in_range",
    "uniform_step",
    "verdicts",
    "write_text",
]
