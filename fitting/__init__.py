"""fitting: inverse identification of G0, G1, η1, Δγ from measured force–displacement curves.

Data in (:mod:`fitting._data`): :class:`Curve` and the loaders :func:`load_curve`,
:func:`load_csv`, :func:`load_afm`; all SI units (s, m, N).
"""

from ._cli import add_fit_arguments as add_fit_arguments  # noqa: E402
from ._cli import run_fit as run_fit  # noqa: E402
from ._data import DEFAULT_LIMITS as DEFAULT_LIMITS
from ._data import SEGMENT_KINDS as SEGMENT_KINDS
from ._data import ContactPoint as ContactPoint
from ._data import Curve as Curve
from ._data import Limits as Limits
from ._data import infer_segments as infer_segments
from ._data import load_afm as load_afm
from ._data import load_csv as load_csv
from ._data import load_curve as load_curve
from ._data import parse_units as parse_units
from ._data import preprocess as preprocess
from ._data import resample as resample
from ._data import select_segments as select_segments
from ._data import unit_factor as unit_factor

# --- fitting (objective, optimiser, uncertainty, report, CLI) ----------------------------
from ._objective import CurveBatch as CurveBatch  # noqa: E402
from ._objective import ModelSpec as ModelSpec  # noqa: E402
from ._objective import initial_guess as initial_guess  # noqa: E402
from ._objective import make_spec as make_spec  # noqa: E402
from ._objective import prepare_curves as prepare_curves  # noqa: E402
from ._objective import residuals as residuals  # noqa: E402
from ._optimise import OPTIMISERS as OPTIMISERS  # noqa: E402
from ._optimise import FitResult as FitResult  # noqa: E402
from ._optimise import fit as fit  # noqa: E402
from ._optimise import solve as solve  # noqa: E402
from ._optimise import solve_batch as solve_batch  # noqa: E402
from ._report import write_report as write_report  # noqa: E402
from ._uncertainty import IdentifiabilityWarning as IdentifiabilityWarning  # noqa: E402
from ._uncertainty import profile_likelihood as profile_likelihood  # noqa: E402
