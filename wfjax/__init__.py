"""wfjax: JAX-accelerated, differentiable simulation of railway wheel-flat impact forces.

Reproduces and extends the time-domain wheel/rail interaction model of Pieringer, Kropp &
Nielsen (2014), Wear 314, 273-281. SI units throughout the Python API.

Precision: importing wfjax switches on ``jax_enable_x64`` -- the one place in the package where
JAX configuration is touched: the setup (track modes, 3D tables, trajectories) is always
float64. The time loop runs in float32 for forward runs and in float64 where gradients are
taken (``SimConfig(precision="auto")``, the default; ``"float64"`` or ``"float32"`` force one:
the command line's ``--precision``, case key ``config.precision``, environment
``WFJAX_PRECISION``).
"""

import jax as _jax

if not _jax.config.read("jax_enable_x64"):
    _jax.config.update("jax_enable_x64", True)

from . import contact as contact  # noqa: E402  (after the x64 switch)
from . import params as params
from ._cache import load_or_build as load_or_build
from .api import SimResult as SimResult
from .api import simulate as simulate
from .model import geometry as geometry
from .model import sleepers as sleepers
from .model import supports as supports
from .model import track as track
from .model import wheel as wheel
from .model.greens import MovingGreens as MovingGreens
from .model.track import ModalModel as ModalModel
from .model.vehicle import Vehicle as Vehicle
from .model.wheel import WheelModal as WheelModal
from .params import Flat as Flat
from .params import Material as Material
from .params import SimConfig as SimConfig
from .params import Track as Track
from .params import Wheel as Wheel
from .params import kmh as kmh
from .params import mm as mm
from .program.core import compile_scenario as compile_scenario
from .scenario import roughness as roughness
from .scenario.description import Scenario as Scenario
from .scenario.joint import Joint as Joint
from .scenario.roughness import Roughness as Roughness
from .scenario.sensors import Detector as Detector
from .scenario.windows import impact_position_from_angle as impact_position_from_angle
from .sweeps import SweepResult as SweepResult
from .sweeps import sweep as sweep

__version__ = "0.1.0"

_LAZY = ("fit", "identify")  # imported on first use: they pull in scipy.stats and optax (~1 s)


def __getattr__(name):
    """``wf.fit`` and ``wf.identify`` (a callable package: ``wf.identify(passages)``), imported
    on first access so that ``import wfjax`` stays fast for simulate and sweep."""
    if name in _LAZY:
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'wfjax' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_LAZY))
