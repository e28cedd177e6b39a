"""Forward sweeps over parameter grids: labelled results, chunks, devices, processes.

See `sweep` (`_sweep.py`), the models (`_models.py`: the duration of the lift and the
separation work), the parameters and their scaling (`_parameters.py`) and the execution on
devices and processes (`_run.py`).
"""

from ._models import AbstractSweepModel as AbstractSweepModel
from ._models import ApproachHoldLift as ApproachHoldLift
from ._models import RelaxedStart as RelaxedStart
from ._sweep import SUMMARIES as SUMMARIES
from ._sweep import sweep as sweep
