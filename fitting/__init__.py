"""fitting: inverse identification of the rheology, Δγ and the contact point from measured
force–displacement curves (SI units: s, m, N; indentation positive into the sample,
compressive force positive, adhesion negative).

Data in: :class:`Curve` and the loaders :func:`load_curve`, :func:`load_csv`,
:func:`load_afm` with :func:`preprocess` (baseline, tip position, contact point: the
registered steps :func:`preprocessing_steps`).
Identification: :func:`fit` (global search, uncertainty) → :class:`FitResult`, its options
as keywords or one checked object :class:`FitOptions` (:class:`BatchOptions` for the
scheduling of :func:`fit_each`);
:func:`write_report` (``parameters.json``, ``parameters.csv``, ``fit.csv``);
:func:`profile_likelihood`; :func:`sample` (the posterior of a fit by NUTS,
numpyro) → :class:`PosteriorResult`; :func:`fit_each` (force maps, many curves: one fit per
curve in batched compiled calls) → :class:`FitEachResult`; :func:`solve` /
:func:`solve_batch` for many problems.
"""

from ._batch import FitEachResult as FitEachResult
from ._batch import fit_each as fit_each
from ._curve import DEFAULT_LIMITS as DEFAULT_LIMITS
from ._curve import SEGMENT_KINDS as SEGMENT_KINDS
from ._curve import ContactPoint as ContactPoint
from ._curve import Curve as Curve
from ._curve import DataError as DataError
from ._curve import Limits as Limits
from ._curve import infer_segments as infer_segments
from ._curve import resample as resample
from ._curve import select_segments as select_segments
from ._io_afm import FailedCurve as FailedCurve
from ._io_afm import load_afm as load_afm
from ._io_csv import load_csv as load_csv
from ._least_squares import LBFGS as LBFGS
from ._least_squares import RESULTS as RESULTS
from ._least_squares import LevenbergMarquardt as LevenbergMarquardt
from ._least_squares import Solution as Solution
from ._load import load_curve as load_curve
from ._load import supported_formats as supported_formats
from ._objective import effective_force as effective_force
from ._objective import predict as predict
from ._objective import residuals as residuals
from ._optimise import fit as fit
from ._optimise import solve as solve
from ._optimise import solve_batch as solve_batch
from ._options import DEFAULT_ABANDON as DEFAULT_ABANDON
from ._options import DEFAULT_EXPLORE_STEPS as DEFAULT_EXPLORE_STEPS
from ._options import DEFAULT_LOCAL_ROUNDS as DEFAULT_LOCAL_ROUNDS
from ._options import DEFAULT_SCREEN as DEFAULT_SCREEN
from ._options import DEFAULT_STARTS as DEFAULT_STARTS
from ._options import OPTIMISERS as OPTIMISERS
from ._options import BatchOptions as BatchOptions
from ._options import FitOptions as FitOptions
from ._parameters import Parameterisation as Parameterisation
from ._parameters import make_parameterisation as make_parameterisation
from ._posterior import PosteriorResult as PosteriorResult
from ._posterior import PosteriorWarning as PosteriorWarning
from ._posterior import sample as sample
from ._prepare import CurveBatch as CurveBatch
from ._prepare import check_segments as check_segments
from ._prepare import prepare_curves as prepare_curves
from ._prepare import select_samples as select_samples
from ._prepare import stack_batches as stack_batches
from ._preprocess import preprocess as preprocess
from ._preprocess import preprocessing_steps as preprocessing_steps
from ._profile import profile_likelihood as profile_likelihood
from ._report import result_table as result_table
from ._report import write_each_report as write_each_report
from ._report import write_report as write_report
from ._result import FitResult as FitResult
from ._result import ModelChoice as ModelChoice
from ._spec import ModelSpec as ModelSpec
from ._spec import make_spec as make_spec
from ._spec import parameter_info as parameter_info
from ._start import DataScales as DataScales
from ._start import data_scales as data_scales
from ._start import default_bounds as default_bounds
from ._start import initial_guess as initial_guess
from ._uncertainty import IdentifiabilityWarning as IdentifiabilityWarning
from ._uncertainty import ModelValidityWarning as ModelValidityWarning
from ._units import parse_units as parse_units
from ._units import unit_factor as unit_factor
from ._xla import XLA_CPU_FLAGS as XLA_CPU_FLAGS
from ._xla import tune_xla_cpu as tune_xla_cpu


def _run_in_float64() -> None:
    """The entry functions run in float64 when called eagerly, whatever the caller's
    ``jax_enable_x64`` (importing ``fitting`` or ``jaxcontact`` leaves it alone; see
    ``jaxcontact._solvers.float64_scope``)."""
    from jaxcontact._solvers import float64_scope

    names = ("fit", "fit_each", "solve", "solve_batch", "profile_likelihood", "predict",
             "residuals", "effective_force", "preprocess", "prepare_curves", "select_samples",
             "stack_batches", "initial_guess", "data_scales", "default_bounds",
             "make_parameterisation", "make_spec", "resample", "select_segments",
             "infer_segments", "load_curve", "load_csv", "load_afm", "write_report",
             "write_each_report", "result_table", "sample")
    for name in names:
        globals()[name] = float64_scope(globals()[name])


_run_in_float64()
