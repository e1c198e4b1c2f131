"""Contact laws: Hertz spring, 2D Winkler bedding and 3D Kalker (elastic half-space)."""

from . import hertz as hertz
from . import kalker as kalker
from . import tables as tables
from . import winkler as winkler
