"""planning stage: side and forward steps from scallop height and chord tolerance (METHOD section 4)."""

from conformill.planning.steps import (
    check_params,
    check_stock,
    domain_forward_step,
    domain_side_step,
    forward_step,
    polar_forward_step,
    polar_metric,
    polar_side_step,
    scallop_height,
    side_interval,
    side_interval_paper,
    side_interval_stock,
)

__all__ = [
    "check_params",
    "check_stock",
    "side_interval",
    "side_interval_stock",
    "scallop_height",
    "side_interval_paper",
    "forward_step",
    "domain_side_step",
    "domain_forward_step",
    "polar_metric",
    "polar_side_step",
    "polar_forward_step",
]
