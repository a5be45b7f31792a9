"""
Scene files on disk: finding one by name, reading it, and laying it over its base.

A scene file names only what it changes. Its keys are laid over its base: the scene its
top-level ``base:`` key names (a name in config/, or a path relative to the file when it holds
a path separator or ends in .yaml), else the shipped defaults (config/default.yaml). The base
may name a base of its own. Mappings merge key by key (``physics``, ``structure``, ``dets.left``,
...); any other value, a list included, replaces the base's. A mapping given to ``load_scene``
takes a base only when it names one (its paths are relative to the working directory): without
``base:`` it must be complete, as the scene stored in a log is.
"""

from __future__ import annotations

import os
import sys

import yaml

from .keys import SceneError, SECTIONS

__all__ = ['BASE_KEY', 'DEFAULT_SCENE', 'config_dirs', 'find_config', 'scene_names',
           'resolve_base', 'read_scene_file']

BASE_KEY = 'base'
DEFAULT_SCENE = 'default'


def config_dirs() -> list:
    """
    Return the folders searched for a scene name, in search order.

    The ament index share directory (colcon installs), ``<sys.prefix>/share`` (pip installs)
    and the source tree.
    """
    folders = []
    try:
        from ament_index_python.packages import get_package_share_directory
        folders.append(os.path.join(get_package_share_directory('det_sim_ros'), 'config'))
    except Exception:  # no ament environment: fall back to the prefix and the source tree
        pass
    folders.append(os.path.join(sys.prefix, 'share', 'det_sim_ros', 'config'))
    folders.append(os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(
        os.path.abspath(__file__)))), 'config'))
    return folders


def _is_scene_file(path) -> bool:
    """Return True if the YAML file at ``path`` reads as a scene (not a fleet file, say)."""
    try:
        data = unwrap_ros_params(_read_yaml(path), path)
    except SceneError:
        return False
    return BASE_KEY in data or any(section in data for section in SECTIONS)


def scene_names(folders=None) -> list:
    """Return the names of the scene files in ``folders`` (default: :func:`config_dirs`)."""
    names = set()
    for folder in config_dirs() if folders is None else folders:
        if not os.path.isdir(folder):
            continue
        for entry in os.listdir(folder):
            if entry.endswith('.yaml') and _is_scene_file(os.path.join(folder, entry)):
                names.add(entry[:-len('.yaml')])
    return sorted(names)


def find_config(name: str = 'default.yaml') -> str:
    """
    Locate an installed scene file by name.

    Looks in :func:`config_dirs`, in that order. A path to an existing file is returned as is.
    A name found nowhere is refused with one line listing the scenes found and the folders.
    """
    if os.path.isfile(name):
        return name
    folders = config_dirs()
    path = _installed(name, folders)
    if path is None:
        raise SceneError(f'scene file {name!r} not found: ' + _what_there_is(folders))
    return path


def _installed(name: str, folders) -> str | None:
    """Return the path of scene ``name`` (.yaml optional) in the first folder that has it."""
    file_name = name if name.endswith('.yaml') else name + '.yaml'
    for folder in folders:
        path = os.path.join(folder, file_name)
        if os.path.isfile(path):
            return path
    return None


def _what_there_is(folders) -> str:
    """Return the scenes found in ``folders`` and the folders, for a name found nowhere."""
    found = scene_names(folders)
    return ('no such file and no scene of that name; scenes: ' + (', '.join(found) or 'none')
            + ' (looked in ' + ', '.join(folders) + ')')


def _read_yaml(path):
    try:
        with open(path, encoding='utf-8') as stream:
            return yaml.safe_load(stream)
    except OSError as exc:
        raise SceneError(f'cannot read scene file {path!r}: {exc.strerror}') from None
    except UnicodeDecodeError as exc:
        raise SceneError(f'scene file {path!r} is not UTF-8 text (byte {exc.start}): '
                         'a YAML scene file was expected') from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' at line {mark.line + 1}' if mark is not None else ''
        raise SceneError(f'malformed YAML in {path!r}{where}: {exc}') from None


def unwrap_ros_params(data, origin):
    """Accept ``{node: {ros__parameters: {...}}}`` (or ``/**``) as well as a bare mapping."""
    if not isinstance(data, dict):
        raise SceneError(f'scene {origin}: top level must be a mapping, got {type(data).__name__}')
    if len(data) == 1:
        (only, inner), = data.items()
        if isinstance(inner, dict) and 'ros__parameters' in inner:
            data = inner['ros__parameters']
            if not isinstance(data, dict):
                raise SceneError(f'scene {origin}: ros__parameters must be a mapping')
    return data


def _merged(base: dict, changes: dict) -> dict:
    """Return ``base`` with ``changes`` laid over it: mappings key by key, other values whole."""
    result = dict(base)
    for key, value in changes.items():
        below = result.get(key)
        if isinstance(below, dict) and value is None:
            continue        # an empty section (every key commented out) changes nothing
        result[key] = _merged(below, value) if isinstance(below, dict) and isinstance(
            value, dict) else value
    return result


def _base_path(base, folder: str, origin: str) -> str:
    """Return the file a ``base:`` value names: a path relative to ``folder`` or a scene name."""
    if not isinstance(base, str) or not base:
        raise SceneError(f"scene {origin}: 'base' must be a scene name or a path "
                         f'(got {base!r})')
    if os.sep in base or base.endswith(('.yaml', '.yml')):
        path = os.path.join(folder, base)
        if not os.path.isfile(path):
            raise SceneError(f'scene {origin}: base {base!r} not found (no file {path})')
        return path
    folders = config_dirs()
    path = _installed(base, folders)
    if path is None:
        raise SceneError(f'scene {origin}: base {base!r} not found: '
                         + _what_there_is(folders))
    return path


def resolve_base(data: dict, folder: str, origin: str, chain: tuple = ()) -> dict:
    """
    Return the scene mapping ``data`` laid over the base it names (its bases in turn).

    ``folder`` is where a relative base path starts; ``chain`` holds the real paths of the
    files that led here, so a base that names one of them is refused as a cycle.
    """
    if BASE_KEY not in data:
        return data
    changes = dict(data)
    path = _base_path(changes.pop(BASE_KEY), folder, origin)
    real = os.path.realpath(path)
    if real in chain:
        names = [os.path.basename(p) for p in chain + (real,)]
        raise SceneError(f'scene {origin}: base cycle ' + ' -> '.join(names))
    return _merged(read_scene_file(path, chain + (real,)), changes)


def read_scene_file(path: str, chain: tuple = ()) -> dict:
    """
    Return the complete scene mapping of the file at ``path``, its bases resolved.

    A file without ``base:`` is laid over the shipped defaults, unless it is that file.
    """
    data = unwrap_ros_params(_read_yaml(path), repr(path))
    real = os.path.realpath(path)
    chain = chain or (real,)
    if BASE_KEY not in data:
        defaults = os.path.realpath(find_config(DEFAULT_SCENE))
        if real == defaults:
            return data
        data = dict(data, **{BASE_KEY: DEFAULT_SCENE})
    return resolve_base(data, os.path.dirname(os.path.abspath(path)), repr(path), chain)
