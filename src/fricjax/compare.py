"""The identification exercise behind `fricjax compare`, as a public namespace: `fj.compare.default_models()`.

The recipe registry (`default_models`: each physics model's start from the data's scales and its fit recipe),
data splits (`Split`, `load_split`), fitting and exact-mode scoring (`fit_and_score`, `score`), ensembles of
the fitted models (`add_ensembles`) and the comparison table (`format_table`). Figures:
`plot_prediction_errors`, `plot_test_loops`.

```python
>>> import fricjax as fj
>>> sorted(fj.compare.default_models())[:3]
['dnlrx', 'gms', 'lugre']
```
"""

from ._plot import plot_prediction_errors as plot_prediction_errors
from ._plot import plot_test_loops as plot_test_loops
from ._protocols._compare import CompareError as CompareError
from ._protocols._compare import DataScales as DataScales
from ._protocols._compare import ModelScore as ModelScore
from ._protocols._compare import ModelSpec as ModelSpec
from ._protocols._compare import Split as Split
from ._protocols._compare import add_ensembles as add_ensembles
from ._protocols._compare import count_parameters as count_parameters
from ._protocols._compare import default_models as default_models
from ._protocols._compare import fit_and_score as fit_and_score
from ._protocols._compare import format_table as format_table
from ._protocols._compare import load_split as load_split
from ._protocols._compare import score as score
