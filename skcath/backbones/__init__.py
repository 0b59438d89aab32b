"""Backbones: nominal tip position from motor angles, calibrated per run (or once)."""

from ._backbone import BACKBONE_COLUMNS, PCCBackbone, PDLBackbone
from ._hysteresis import identify_play_width, play_kernel, play_operator
from ._pi import PrandtlIshlinskii, pi_inverse_step, pi_step
from ._lm import LMResult, levenberg_marquardt
from ._pcc import PCCParams, calibrate_pcc, pcc_kernel, pcc_tip
from ._pdl import PDLParams, calibrate_pdl, pdl_kernel, pdl_tip
from ._polynomial import PolynomialBackbone, PolynomialParams, polynomial_kernel, polynomial_tip

__all__ = [
    "BACKBONE_COLUMNS",
    "LMResult",
    "PCCBackbone",
    "PCCParams",
    "PDLBackbone",
    "PDLParams",
    "PolynomialBackbone",
    "PolynomialParams",
    "PrandtlIshlinskii",
    "calibrate_pcc",
    "calibrate_pdl",
    "identify_play_width",
    "levenberg_marquardt",
    "pcc_kernel",
    "pcc_tip",
    "pdl_kernel",
    "pdl_tip",
    "pi_inverse_step",
    "pi_step",
    "play_kernel",
    "play_operator",
    "polynomial_kernel",
    "polynomial_tip",
]
