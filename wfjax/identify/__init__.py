"""Wheel flats from a wayside detector's readings of a passing train (``docs/identify.md``).

One job per module: :mod:`~wfjax.identify.passage` (the readings CSV), :mod:`~.forward`
(the forward model through the program core), :mod:`~.inference` (the grid posterior),
:mod:`~.rules` (flag and maintenance rules), :mod:`~.pipeline` (:func:`identify`),
:mod:`~.report` (CSV, JSON, PNG, terminal lines) and :mod:`~.synthetic` (passages for a
chosen train, the validation's truth).
"""

import sys as _sys
import types as _types

from .inference import Prior as Prior
from .passage import Passage as Passage
from .passage import PassageError as PassageError
from .passage import passages_csv as passages_csv
from .passage import read_passages as read_passages
from .pipeline import Identification as Identification
from .pipeline import identify as identify
from .rules import FRA as FRA
from .rules import TRAFIKVERKET as TRAFIKVERKET
from .rules import RuleSet as RuleSet


class _CallablePackage(_types.ModuleType):
    """``wfjax.identify`` is this package and, called, :func:`identify`."""

    def __call__(self, *args, **kwargs):
        return identify(*args, **kwargs)


_sys.modules[__name__].__class__ = _CallablePackage
