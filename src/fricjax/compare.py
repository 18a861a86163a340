"""The identification exercise behind `fricjax compare`, as a public namespace: `fj.compare.default_models()`.

The recipe registry (`default_models`: each model's start from the training record and its fit recipe; the
names in `PHYSICS_MODELS`, fitted by default, `NEURAL_MODELS` and `LINEAR_MODELS`, `MODEL_NAMES` for all),
data (`load_record_spec`, `load_split`, `split_record`, `Split`, `TestRecord`: a test part or another record, with an
initialisation window that estimates the force offset), budgets (`FitSettings`), fitting and exact-mode scoring
(`fit_and_score`, `free_run`, `score`, `score_prediction`, `reference_scores`: the noise floor;
`paired_validation_gain`: whether a neural model's output-error stage improved on its least-squares start), ensembles of
the fitted models (`add_ensembles`) and the comparison table (`format_table`). Figures:
`plot_prediction_errors`, `plot_test_loops`.

```python
>>> import fricjax as fj
>>> sorted(fj.compare.default_models())[:3]
['avd', 'dnlrx', 'gms']
```
"""

from ._plot import plot_prediction_errors as plot_prediction_errors
from ._plot import plot_test_loops as plot_test_loops
from ._protocols._compare import LINEAR_MODELS as LINEAR_MODELS
from ._protocols._compare import MODEL_NAMES as MODEL_NAMES
from ._protocols._compare import NEURAL_MODELS as NEURAL_MODELS
from ._protocols._compare import PHYSICS_MODELS as PHYSICS_MODELS
from ._protocols._compare import RESULT_CODES as RESULT_CODES
from ._protocols._compare import CompareError as CompareError
from ._protocols._compare import DataScales as DataScales
from ._protocols._compare import FitSettings as FitSettings
from ._protocols._compare import LoadedRecord as LoadedRecord
from ._protocols._compare import ModelScore as ModelScore
from ._protocols._compare import ModelSpec as ModelSpec
from ._protocols._compare import Score as Score
from ._protocols._compare import Split as Split
from ._protocols._compare import TestRecord as TestRecord
from ._protocols._compare import add_ensembles as add_ensembles
from ._protocols._compare import count_parameters as count_parameters
from ._protocols._compare import default_init_window as default_init_window
from ._protocols._compare import default_models as default_models
from ._protocols._compare import fit_and_score as fit_and_score
from ._protocols._compare import format_table as format_table
from ._protocols._compare import free_run as free_run
from ._protocols._compare import load_record_spec as load_record_spec
from ._protocols._compare import load_split as load_split
from ._protocols._compare import paired_validation_gain as paired_validation_gain
from ._protocols._compare import reference_scores as reference_scores
from ._protocols._compare import score as score
from ._protocols._compare import score_prediction as score_prediction
from ._protocols._compare import split_record as split_record
from ._protocols._compare import statistics_warnings as statistics_warnings
