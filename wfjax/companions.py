"""Keys that act only together with another: given alone they would be silently ignored, so
they are refused, each with one line naming what the user typed (flag, ``--set`` or the case
file's key) and the companion it needs.

A key counts as given when the user set it (flag, ``--set`` or case file) to a value other
than the command's default: a case file written by ``wfjax`` (``case.toml``, a JSON summary)
holds every key at its default, and repeating it stays possible.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from .options import KEYS, CaseError, fmt

__all__ = ["COMPANIONS", "check_companions"]


def _is(path: str, *values) -> Callable[[Mapping], bool]:
    return lambda v: v.get(path) in values


def _set(path: str) -> Callable[[Mapping], bool]:
    return lambda v: v.get(path) not in (None, [], "")


def _positive(path: str) -> Callable[[Mapping], bool]:
    return lambda v: float(v.get(path) or 0.0) > 0


def _preset_without_positions(*presets: str) -> Callable[[Mapping], bool]:
    return lambda v: v.get("vehicle.preset") in presets and v.get("vehicle.positions") is None


_ISO = (_is("roughness.preset", "iso3095"), 'roughness.preset = "iso3095" (--roughness '
        "iso3095)")
_VOIDS = (_set("supports.void_sleepers"), "supports.void_sleepers (--void-sleepers)")
_SCATTER = (_positive("supports.scatter_cv"), "supports.scatter_cv > 0 (--scatter-cv)")
_JOINT = (_set("joint.depth"), "joint.depth (--joint-depth-mm)")
_PASSAGE = (_set("passage.csv"), "passage.csv (--passage-csv)")

COMPANIONS: dict[str, tuple[Callable[[Mapping], bool], str]] = {
    "roughness.realisations": _ISO,
    "roughness.seed": _ISO,
    "roughness.length": _ISO,
    "supports.void_gap": _VOIDS,
    "supports.void_remaining": _VOIDS,
    "supports.scatter_seed": _SCATTER,
    "supports.realisations": _SCATTER,
    "joint.position": _JOINT,
    "joint.length": _JOINT,
    "joint.shape": _JOINT,
    "vehicle.axle_spacing": (_preset_without_positions("bogie", "wagon"),
                             'vehicle.preset = "bogie" or "wagon" (--vehicle)'),
    "vehicle.bogie_distance": (_preset_without_positions("wagon"),
                               'vehicle.preset = "wagon" (--vehicle wagon)'),
    "flat.profile_smoothing_mm": (_is("flat.kind", "profile"),
                                  "a measured profile (--profile-csv)"),
    "flat.length": (_is("flat.kind", "rounded", "both"),
                    'a rounded flat (flat.kind = "rounded" or "both"; a new flat\'s length '
                    "follows its depth)"),
    "flat.length_factor": (_is("flat.kind", "rounded", "both"), 'a rounded flat (flat.kind = '
                           '"rounded" or "both")'),
    **{f"passage.{k}": _PASSAGE for k in ("train", "flats", "speed_kmh", "noise", "seed")},
    **{f"flat.section_{k}_mm": (_is("flat.kind", "sections"), "flat.sections (--sections)")
       for k in ("positions", "window")},
}
"""``key -> (does the case have its companion?, the companion in words)``."""


def _companion_keys(words: str) -> set[str]:
    """The case keys named in a companion's words (``supports.void_sleepers``)."""
    return {k for k in KEYS if k in words}


def check_companions(values: Mapping, defaults: Mapping, given: Mapping[str, str],
                     unset: set[str] = frozenset()) -> None:
    """Refuse a key the user gave whose companion is missing.

    Args:
        values: the merged case values (SI).
        defaults: the command's default values (a key at its default is not refused).
        given: ``{key: how the user typed it}`` (``"--realisations"``, ``"case.toml:
            roughness.realisations"``) of the keys the user set.
        unset: keys a caller unset on purpose (``resolve(..., {"joint.depth": None})``):
            the keys that need them are dropped knowingly, not refused.

    Raises:
        CaseError: ``<typed> <value>: ignored without <companion>; give it, or drop <typed>``.
    """
    for path, (present, companion) in COMPANIONS.items():
        if path not in given or path not in values or values[path] == defaults.get(path) \
                or _companion_keys(companion) & set(unset):
            continue
        if not present(values):
            value = values[path] / (KEYS[path].factor if given[path].startswith("--")
                                    and not given[path].startswith("--set") else 1.0) \
                if isinstance(values[path], float) else values[path]
            raise CaseError(f"{given[path]} {fmt(value)}: has no effect without {companion}; "
                            f"give that too, or drop {given[path]}")
