"""fitting: inverse identification of G0, G1, η1, Δγ from measured force–displacement curves.

Data in: :class:`Curve` and the loaders :func:`load_curve`,
:func:`load_csv`, :func:`load_afm`; all SI units (s, m, N).
"""

from ._curve import DEFAULT_LIMITS as DEFAULT_LIMITS
from ._curve import SEGMENT_KINDS as SEGMENT_KINDS
from ._curve import ContactPoint as ContactPoint
from ._curve import Curve as Curve
from ._curve import DataError as DataError
from ._curve import Limits as Limits
from ._curve import infer_segments as infer_segments
from ._curve import resample as resample
from ._curve import select_segments as select_segments
from ._io_afm import load_afm as load_afm
from ._io_csv import load_csv as load_csv
from ._load import load_curve as load_curve
from ._load import supported_formats as supported_formats
from ._objective import CurveBatch as CurveBatch
from ._objective import ModelSpec as ModelSpec
from ._objective import initial_guess as initial_guess
from ._objective import make_spec as make_spec
from ._objective import prepare_curves as prepare_curves
from ._objective import residuals as residuals
from ._optimise import OPTIMISERS as OPTIMISERS
from ._optimise import FitResult as FitResult
from ._optimise import fit as fit
from ._optimise import solve as solve
from ._optimise import solve_batch as solve_batch
from ._preprocess import preprocess as preprocess
from ._profile import profile_likelihood as profile_likelihood
from ._report import write_report as write_report
from ._uncertainty import IdentifiabilityWarning as IdentifiabilityWarning
from ._units import parse_units as parse_units
from ._units import unit_factor as unit_factor
from ._xla import XLA_CPU_FLAGS as XLA_CPU_FLAGS
from ._xla import tune_xla_cpu as tune_xla_cpu
