"""Contact laws: Hertz spring, 2D Winkler bedding and 3D Kalker (elastic half-space).

:mod:`.laws` puts every model behind one interface (``prepare`` -> a law pytree that the time
loop evaluates); :mod:`.newton` solves each step's scalar contact equation.
"""

from . import hertz as hertz
from . import kalker as kalker
from . import laws as laws
from . import newton as newton
from . import tables as tables
from . import winkler as winkler
