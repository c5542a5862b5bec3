"""The thesis's experiments (chapter 7) on the synthetic rig, and campaigns
on a stored image database: the wiring layer over the recognizer, the trial
driver and the rigs.

``prepare`` renders the training database and trains the DB1 and DB2 sensor
models (cached in the work folder); ``run_case`` runs one case with several
planners on the *same* trials (same poses, initial configurations and
occluder layouts per trial) and returns the thesis-shaped tables.
Observations are rendered images with capture noise — never samples of the
Gaussian model under test.  ``Settings.stride`` thins the thesis's 32 x 7
table (every ``stride``-th position per camera) for quick runs; each stride
has its own cached database and models.

``run_dataset`` runs the same protocol (every object, random pose and start
per trial, planners on the same trials) on any image database in the folder
+ ``manifest.csv`` format with a trained model file: a
:class:`~jaxrecog.hardware.DatasetRig` replays its ``test`` split, with as
many cameras and positions as the model has.

One idea per module:

================ ==========================================================
``settings``     :class:`Settings`, everything that defines a run, and its checks
``naming``       cache naming: database folders, model files, run ids, result folders
``stores``       trial stores keyed by what their trials depend on (settings, model, data digests)
``cases``        the case table (:data:`CASES`), a case's settings, model and trials
``preparation`` rendering and training (cached): :func:`prepare`
``rigs``         the synthetic rig, its pool for the lockstep slots, worker processes
``reports``      :class:`CaseReport`: tables, the thesis's rows, Markdown / JSON
``run``          the thesis cases' campaigns: :func:`run_case`, :func:`run_trace`
``dataset``      a campaign on an image database: :func:`run_dataset`
``turntable``    the turntable set and its campaign: :func:`run_turntable`
``held_out``     held-out captures of a case, drawn like its own, for what a recipe fits on a ``calib`` split
================ ==========================================================

The capture noise and the cardboard boards of a trial's scene are
:mod:`jaxrecog.scene`'s (the CLI reads them without this package).
"""

from .cases import CASES, JITTER, Case, case_model, case_settings, case_trials, off_grid
from .dataset import DATASET_PLANNERS, dataset_planners, run_dataset
from .naming import model_path, results_dir
from .preparation import Prepared, prepare
from .reports import CaseReport
from .rigs import capture_pool, make_rig, rig_pool, rig_table, rig_tag
from .run import campaign_recognizer, compare_planners, run_case, run_trace
from .settings import Settings
from .turntable import TURNTABLE_PLANNERS, prepare_turntable, run_turntable

__all__ = [
    "Case", "CASES", "JITTER", "case_settings", "case_model", "case_trials", "off_grid",
    "Settings", "Prepared", "CaseReport", "prepare", "make_rig", "model_path", "results_dir",
    "capture_pool", "rig_pool", "rig_table", "rig_tag", "campaign_recognizer", "compare_planners",
    "run_case", "run_trace", "DATASET_PLANNERS", "dataset_planners", "run_dataset",
    "TURNTABLE_PLANNERS", "prepare_turntable", "run_turntable",
]
