"""jaxcontact: differentiable adhesive contact of viscoelastic bodies in JAX.

The forward model of Popov et al., "Energetic criterion for adhesion in viscoelastic
contacts with non-entropic surface interaction": the Method of Dimensionality Reduction
(MDR) with the energetic (glass-modulus) detachment criterion.

Conventions (everywhere): SI units; indentation depth `d` positive into the sample; normal
force positive when compressive, negative when adhesive; `work_of_adhesion` is the work of
separation per unit area Δγ [J/m²]. Moduli are shear moduli G [Pa] of an incompressible
half-space, so the MDR foundation stiffness is 4G per unit length (E* = 4G).

Precision: importing the library leaves JAX's configuration alone (``jax_enable_x64``
stays as the caller set it). Called directly, every public function, constructor and
profile or rheology method runs with 64-bit types switched on for its own duration
(``jax.enable_x64``, local to the calling thread; `_solvers.float64_scope`), so results are
float64 unless every floating input is float32, in which case the computation runs in
float32 (Python floats and NumPy's float64 arrays are float64 inputs; see the README for
the measured float32 error). Inside the caller's own `jit`, `grad` or `vmap` the caller's
setting holds (JAX lowers and differentiates that program after the call returns): with x64
off it runs in float32; switch x64 on (``jax.config.update("jax_enable_x64", True)``, or
``with jax.enable_x64(True):`` around the transformed call) for float64 there. The returned
arrays keep their dtype; with x64 off JAX truncates float64 arrays to float32 (with its
warning) in the caller's own later operations.

Inputs are checked eagerly (`ValueError`) and under `jit`/`vmap` (`.result` per lane,
`throw=`), including the plausibility of their units (`plausibility_checks`).
"""

# ruff: noqa: I001
from ._version import __version__ as __version__  # noqa: E402

# --- profiles --------------------------------------------------------------------------
from ._profiles import AbstractProfile as AbstractProfile  # noqa: E402
from ._profiles import AbstractCurvedProfile as AbstractCurvedProfile  # noqa: E402
from ._profiles import AbstractPowerLawProfile as AbstractPowerLawProfile  # noqa: E402
from ._profiles import Cone as Cone  # noqa: E402
from ._profiles import FlatPunch as FlatPunch  # noqa: E402
from ._profiles import Parabola as Parabola  # noqa: E402
from ._profiles import PowerLaw as PowerLaw  # noqa: E402
from ._profiles import power_law_factor as power_law_factor  # noqa: E402

# --- further exports (one line each, added by module) ------------------------------------
from ._criteria import BEM_CHI as BEM_CHI  # noqa: E402
from ._criteria import bem_critical_stress as bem_critical_stress  # noqa: E402
from ._criteria import bem_release_energy as bem_release_energy  # noqa: E402
from ._criteria import critical_elongation as critical_elongation  # noqa: E402
from ._criteria import critical_line_load as critical_line_load  # noqa: E402
from ._criteria import hess_elongation as hess_elongation  # noqa: E402
from ._tabulated import Tabulated as Tabulated  # noqa: E402
from ._probes import Sphere as Sphere  # noqa: E402
from ._probes import SPHERE_LIMIT as SPHERE_LIMIT  # noqa: E402
from ._probes import PARABOLA_LIMIT as PARABOLA_LIMIT  # noqa: E402
from ._probes import PYRAMID_FACTORS as PYRAMID_FACTORS  # noqa: E402
from ._probes import pyramid as pyramid  # noqa: E402
from ._probes import pyramid_cone_angle as pyramid_cone_angle  # noqa: E402
from ._probes import tabor_parameter as tabor_parameter  # noqa: E402
from ._probes import TABOR_SEPARATION as TABOR_SEPARATION  # noqa: E402
from ._probes import ProfileValidity as ProfileValidity  # noqa: E402
from ._probes import profile_validity as profile_validity  # noqa: E402
from ._probes import depth_limit as depth_limit  # noqa: E402
from ._rheology import AbstractRheology as AbstractRheology  # noqa: E402
from ._rheology import CreepChain as CreepChain  # noqa: E402
from ._rheology import Elastic as Elastic  # noqa: E402
from ._rheology import PronySeries as PronySeries  # noqa: E402
from ._rheology import StandardModel as StandardModel  # noqa: E402
from ._foundation import simulate as simulate  # noqa: E402
from ._foundation import FoundationGrid as FoundationGrid  # noqa: E402
from ._foundation import AbstractLoading as AbstractLoading  # noqa: E402
from ._foundation import DisplacementControl as DisplacementControl  # noqa: E402
from ._foundation import CompliantLoading as CompliantLoading  # noqa: E402
from ._foundation import ForceControl as ForceControl  # noqa: E402
from ._elastic import PullOff as PullOff  # noqa: E402
from ._elastic import contact_pressure as contact_pressure  # noqa: E402
from ._elastic import jkr_contact_radius as jkr_contact_radius  # noqa: E402
from ._elastic import jkr_displacement as jkr_displacement  # noqa: E402
from ._elastic import jkr_force as jkr_force  # noqa: E402
from ._elastic import profile_radius as profile_radius  # noqa: E402
from ._elastic import pull_off as pull_off  # noqa: E402
from ._method import AbstractMethod as AbstractMethod  # noqa: E402
from ._method import DiffraxODE as DiffraxODE  # noqa: E402
from ._method import ExactUpdate as ExactUpdate  # noqa: E402
from ._pulloff import retract as retract  # noqa: E402
from ._solution import RESULTS as RESULTS  # noqa: E402
from ._solution import ContactSolution as ContactSolution  # noqa: E402
from ._solution import BEMDetails as BEMDetails  # noqa: E402
from ._solution import ErrorEstimate as ErrorEstimate  # noqa: E402
from ._solution import FoundationDetails as FoundationDetails  # noqa: E402
from ._solution import RetractDetails as RetractDetails  # noqa: E402
from ._foundation import FoundationState as FoundationState  # noqa: E402
from ._validate import PLAUSIBLE as PLAUSIBLE  # noqa: E402
from ._validate import plausibility_checks as plausibility_checks  # noqa: E402
from ._validate import check_plausible as check_plausible  # noqa: E402
from ._bem import BEMGrid as BEMGrid  # noqa: E402
from ._bem import BEMSolution as BEMSolution  # noqa: E402
from ._bem import bem_contact as bem_contact  # noqa: E402
from ._bem import bem_heights as bem_heights  # noqa: E402
from ._bem import bem_simulate as bem_simulate  # noqa: E402
from ._bem import ellipsoid_heights as ellipsoid_heights  # noqa: E402
from ._bem import love_displacement as love_displacement  # noqa: E402
from ._bem import pyramid_heights as pyramid_heights  # noqa: E402
from ._bem import self_affine_heights as self_affine_heights  # noqa: E402
from ._bem import tilted_flat_heights as tilted_flat_heights  # noqa: E402
from ._sweep import AbstractSweepModel as AbstractSweepModel  # noqa: E402
from ._sweep import ApproachHoldLift as ApproachHoldLift  # noqa: E402
from ._sweep import RelaxedStart as RelaxedStart  # noqa: E402
from ._sweep import sweep as sweep  # noqa: E402
