"""The identification exercise behind `fricjax compare`, as a public namespace: `fj.compare.default_models()`.

The whole run as data in and a report out: `run_compare(CompareConfig(...))` (a validated `CompareConfig` whose
errors name its fields; `load_records` loads and checks the records it names, `CompareRecords`) returns the `Report`
(the rows, `table()`, `contents()` of `report.json`, `write(out)`).

The recipe registry (`default_models`: each model's start from the training record and its fit recipe; the
names in `PHYSICS_MODELS`, fitted by default, `NEURAL_MODELS` and `LINEAR_MODELS`, `MODEL_NAMES` for all),
data (`load_record_spec`, `load_split`, `split_record`, `Split`, `TrainingRecords`: several training records of one
device, `TestRecord`: a test part or another record, with an initialisation window that estimates the force offset
and, on another record, the model's initial state: `predict_test_record`), budgets (`FitSettings`), fitting and
exact-mode scoring
(`fit_and_score`, `free_run`, `score`, `score_prediction`, `reference_scores`: the noise floor;
`paired_validation_gain`: whether a neural model's output-error stage improved on its least-squares start, and
whether more GMS elements predict the validation part better), ensembles of
the fitted models (`add_ensembles`) and the comparison table (`format_table`). Figures:
`plot_prediction_errors`, `plot_test_loops` (the best distinct models: `distinct_models`) on one test record (another
than the first: `rows_on_test`), `plot_test_records` (each model's NMSE on each; `short_labels`: the records' names).
`fricjax predict` in Python: `run_predict` (saved models on new records, scored as the test records; `Prediction`).

```python
>>> import fricjax as fj
>>> sorted(fj.compare.default_models())[:3]
['avd', 'dnlrx', 'gms']
```
"""

from ._estimation.loop._plausibility import implausible as implausible
from ._protocols.compare._blackbox_recipes import linear_in_parameters_models as linear_in_parameters_models
from ._protocols.compare._config import CompareConfig as CompareConfig
from ._protocols.compare._config import CompareRecords as CompareRecords
from ._protocols.compare._config import expanded_specs as expanded_specs
from ._protocols.compare._config import load_records as load_records
from ._protocols.compare._ensembles import add_ensembles as add_ensembles
from ._protocols.compare._figures import distinct_models as distinct_models
from ._protocols.compare._figures import plot_prediction_errors as plot_prediction_errors
from ._protocols.compare._figures import plot_test_loops as plot_test_loops
from ._protocols.compare._figures import plot_test_records as plot_test_records
from ._protocols.compare._predict import Prediction as Prediction
from ._protocols.compare._predict import run_predict as run_predict
from ._protocols.compare._recipes import ModelSpec as ModelSpec
from ._protocols.compare._records import LoadedRecord as LoadedRecord
from ._protocols.compare._records import Split as Split
from ._protocols.compare._records import TestRecord as TestRecord
from ._protocols.compare._records import TrainingRecords as TrainingRecords
from ._protocols.compare._records import default_init_window as default_init_window
from ._protocols.compare._records import load_record_spec as load_record_spec
from ._protocols.compare._records import load_split as load_split
from ._protocols.compare._records import short_labels as short_labels
from ._protocols.compare._records import split_record as split_record
from ._protocols.compare._records import statistics_warnings as statistics_warnings
from ._protocols.compare._registry import LINEAR_MODELS as LINEAR_MODELS
from ._protocols.compare._registry import MODEL_NAMES as MODEL_NAMES
from ._protocols.compare._registry import NEURAL_MODELS as NEURAL_MODELS
from ._protocols.compare._registry import PHYSICS_MODELS as PHYSICS_MODELS
from ._protocols.compare._registry import default_models as default_models
from ._protocols.compare._report import Report as Report
from ._protocols.compare._report import format_table as format_table
from ._protocols.compare._run import fit_and_score as fit_and_score
from ._protocols.compare._run import run_compare as run_compare
from ._protocols.compare._scoring import ModelScore as ModelScore
from ._protocols.compare._scoring import Score as Score
from ._protocols.compare._scoring import count_parameters as count_parameters
from ._protocols.compare._scoring import free_run as free_run
from ._protocols.compare._scoring import paired_validation_gain as paired_validation_gain
from ._protocols.compare._scoring import predict_test_record as predict_test_record
from ._protocols.compare._scoring import reference_scores as reference_scores
from ._protocols.compare._scoring import rows_on_test as rows_on_test
from ._protocols.compare._scoring import score as score
from ._protocols.compare._scoring import score_prediction as score_prediction
from ._protocols.compare._settings import RESULT_CODES as RESULT_CODES
from ._protocols.compare._settings import CompareError as CompareError
from ._protocols.compare._settings import DataScales as DataScales
from ._protocols.compare._settings import FitSettings as FitSettings
