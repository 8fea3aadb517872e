from .edmd import LeastSquaresFit, fit_least_squares
from .eigen import Eigenfunctions, IdentificationError, IdentificationWarning, eigenfunctions, real_block
from .identify import IdentifyConfig, auto_scale, identify
from .model import FORMAT_VERSION, KoopmanBilinearModel

__all__ = ["LeastSquaresFit", "fit_least_squares", "Eigenfunctions", "IdentificationError",
           "IdentificationWarning", "eigenfunctions", "real_block", "IdentifyConfig", "auto_scale", "identify",
           "FORMAT_VERSION", "KoopmanBilinearModel"]
