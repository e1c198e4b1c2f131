"""Contact laws: Hertz spring, 2D Winkler bedding and 3D Kalker (elastic half-space).

:mod:`.registry` names the models; :mod:`.laws` builds them (``prepare`` -> a law pytree that
the time loop evaluates through :class:`.protocol.ContactLaw`); :mod:`.table_law` holds the 3D
table law and the tables' on-disk cache; :mod:`.newton` solves each step's scalar contact
equation.
"""

from . import hertz as hertz
from . import kalker as kalker
from . import laws as laws
from . import newton as newton
from . import protocol as protocol
from . import registry as registry
from . import table_law as table_law
from . import tables as tables
from . import winkler as winkler
