"""fricjax: friction models as jit-compiled scan simulators, with smooth and exact stick/slip.

One flat public namespace: `import fricjax as fj`.
"""

from importlib.metadata import PackageNotFoundError as _PackageNotFoundError
from importlib.metadata import version as _version

from ._constraints import AbstractUnwrappable as AbstractUnwrappable
from ._constraints import Fixed as Fixed
from ._constraints import Positive as Positive
from ._constraints import Simplex as Simplex
from ._constraints import trainable_filter as trainable_filter
from ._constraints import unwrap as unwrap
from ._inputs import InputRecord as InputRecord
from ._inputs import Motion as Motion
from ._inputs import MotionSample as MotionSample
from ._metrics import fit_percent as fit_percent
from ._metrics import max_error as max_error
from ._metrics import nmse as nmse
from ._metrics import nrmse as nrmse
from ._metrics import relative_error as relative_error
from ._metrics import rmse as rmse
from ._models._base import AbstractFrictionModel as AbstractFrictionModel
from ._models._base import AbstractModel as AbstractModel
from ._models._base import AbstractSystem as AbstractSystem
from ._models.blackbox._kernel import AbstractKernel as AbstractKernel
from ._models.blackbox._kernel import ExponentialKernel as ExponentialKernel
from ._models.blackbox._kernel import KernelNARX as KernelNARX
from ._models.blackbox._kernel import PolynomialKernel as PolynomialKernel
from ._models.blackbox._kernel import volterra_kernels as volterra_kernels
from ._models.blackbox._narx import GSNN as GSNN
from ._models.blackbox._narx import MLPNARX as MLPNARX
from ._models.blackbox._narx import AbstractNARX as AbstractNARX
from ._models.blackbox._narx import AVDNetwork as AVDNetwork
from ._models.blackbox._polynomial import PolynomialNARX as PolynomialNARX
from ._models.blackbox._polynomial import monomial_terms as monomial_terms
from ._models.blackbox._regressors import NARXRegressors as NARXRegressors
from ._models.blackbox._regressors import NARXState as NARXState
from ._models.blackbox._rnn import RecurrentNetwork as RecurrentNetwork
from ._models.blackbox._rnn import RecurrentNetworkState as RecurrentNetworkState
from ._models.physics._dahl import Dahl as Dahl
from ._models.physics._dahl import DahlState as DahlState
from ._models.physics._gms import GMS as GMS
from ._models.physics._gms import GMSState as GMSState
from ._models.physics._lugre import LuGre as LuGre
from ._models.physics._lugre import LuGreState as LuGreState
from ._models.physics._maxwell_slip import AbstractForceMap as AbstractForceMap
from ._models.physics._maxwell_slip import FIRForces as FIRForces
from ._models.physics._maxwell_slip import MaxwellSlip as MaxwellSlip
from ._models.physics._maxwell_slip import MaxwellSlipState as MaxwellSlipState
from ._models.physics._maxwell_slip import SpringForces as SpringForces
from ._models.physics._static import AbstractStaticFriction as AbstractStaticFriction
from ._models.physics._static import BoPavelescu as BoPavelescu
from ._models.physics._static import Coulomb as Coulomb
from ._models.physics._static import CoulombViscous as CoulombViscous
from ._models.physics._static import Threlfall as Threlfall
from ._models.physics._static import Tustin as Tustin
from ._models.physics._stribeck import AbstractStribeck as AbstractStribeck
from ._models.physics._stribeck import ExponentialStribeck as ExponentialStribeck
from ._models.physics._stribeck import RationalStribeck as RationalStribeck
from ._simulate import simulate as simulate
from ._smoothing import AbstractSmoothing as AbstractSmoothing
from ._smoothing import Exact as Exact
from ._smoothing import Smooth as Smooth
from ._smoothing import exact as exact
from ._smoothing import safe_div as safe_div
from ._smoothing import with_smoothing as with_smoothing

try:
    __version__ = _version("fricjax")
except _PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0"

from . import compare as compare  # noqa: E402 - the public `fj.compare` namespace
from ._cli import main as main  # noqa: E402 - the command line, callable: fj.main(["compare", ...])
from ._data._differentiators import al_alaoui_coefficients as al_alaoui_coefficients
from ._data._differentiators import al_alaoui_derivative as al_alaoui_derivative
from ._data._emps import EMPSRecord as EMPSRecord
from ._data._emps import load_emps as load_emps
from ._data._io import RecordError as RecordError
from ._data._io import load_record as load_record
from ._data._preprocessing import Normaliser as Normaliser
from ._data._preprocessing import butter_filtfilt as butter_filtfilt
from ._data._preprocessing import central_difference as central_difference
from ._data._preprocessing import decimate as decimate
from ._data._preprocessing import detrend_linear as detrend_linear
from ._data._preprocessing import normalise as normalise
from ._data._record import FrictionData as FrictionData
from ._data._record import concatenate as concatenate
from ._data._tribometer import TribometerData as TribometerData
from ._data._tribometer import default_tribometer_model as default_tribometer_model
from ._data._tribometer import make_tribometer as make_tribometer
from ._data._tribometer import model_parameters as model_parameters
from ._estimation._ensemble_fit import ForwardSelection as ForwardSelection
from ._estimation._ensemble_fit import select_forward as select_forward
from ._estimation._fit import fit as fit
from ._estimation._fit import levenberg_marquardt as levenberg_marquardt
from ._estimation._fit import solve_linear as solve_linear
from ._estimation._kernel_narx import KernelNARXCandidate as KernelNARXCandidate
from ._estimation._kernel_narx import KernelNARXResult as KernelNARXResult
from ._estimation._kernel_narx import identify_kernel_narx as identify_kernel_narx
from ._estimation._linear import LstsqResult as LstsqResult
from ._estimation._linear import TermSelection as TermSelection
from ._estimation._linear import covariance as covariance
from ._estimation._linear import lstsq as lstsq
from ._estimation._linear import parameter_std as parameter_std
from ._estimation._linear import select_terms as select_terms
from ._estimation._losses import AbstractLoss as AbstractLoss
from ._estimation._losses import MultipleShootingLoss as MultipleShootingLoss
from ._estimation._losses import OneStepLoss as OneStepLoss
from ._estimation._losses import SimulationLoss as SimulationLoss
from ._estimation._polynomial_narx import PolynomialNARXResult as PolynomialNARXResult
from ._estimation._polynomial_narx import identify_polynomial_narx as identify_polynomial_narx
from ._estimation._result import RESULT_CODES as RESULT_CODES
from ._estimation._result import FitResult as FitResult
from ._estimation._serialise import load_model as load_model
from ._estimation._serialise import save_model as save_model
from ._estimation._strategies import Continuation as Continuation
from ._estimation._strategies import MultiStart as MultiStart
from ._estimation._strategies import ParameterScaling as ParameterScaling
from ._estimation._sweep import SweepResult as SweepResult
from ._estimation._sweep import stack_models as stack_models
from ._estimation._sweep import sweep as sweep
from ._models.combine._ensemble import AbstractEnsemble as AbstractEnsemble
from ._models.combine._ensemble import AverageEnsemble as AverageEnsemble
from ._models.combine._ensemble import WeightedEnsemble as WeightedEnsemble
from ._models.combine._sensor import SensorDrift as SensorDrift
from ._models.combine._sensor import SensorDriftState as SensorDriftState
from ._protocols._emps_idm import EMPSIDMData as EMPSIDMData
from ._protocols._emps_idm import EMPSIDMResult as EMPSIDMResult
from ._protocols._emps_idm import emps_idm_data as emps_idm_data
from ._protocols._emps_idm import fit_emps_idm as fit_emps_idm
from ._protocols._emps_open_loop import EMPSOpenLoopFit as EMPSOpenLoopFit
from ._protocols._emps_open_loop import EMPSOpenLoopLoss as EMPSOpenLoopLoss
from ._protocols._emps_open_loop import fit_emps_open_loop as fit_emps_open_loop
from ._protocols._emps_open_loop import predict_emps_open_loop as predict_emps_open_loop
from ._protocols._emps_open_loop import score_emps_open_loop as score_emps_open_loop
from ._protocols._emps_open_loop import split_emps_record as split_emps_record
from ._systems._emps import EMPSClosedLoop as EMPSClosedLoop
from ._systems._emps import EMPSOpenLoop as EMPSOpenLoop
from ._systems._emps import EMPSPlant as EMPSPlant
from ._systems._emps import EMPSSimulation as EMPSSimulation
from ._systems._emps import emps_open_loop_rmse_mm as emps_open_loop_rmse_mm
from ._systems._emps import simulate_closed_loop as simulate_closed_loop
from ._systems._emps import simulate_open_loop as simulate_open_loop
