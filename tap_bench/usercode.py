"""Code that definition files name: found without running it, checked before anything of it
is called, and fingerprinted for the episode cache.

Suite, scenario and policy files are code, as Stable-Baselines3 models are: a policy file of
kind ``import`` names a class (``"factory": "my_package.policies:MyPolicy"``) and a scenario's
``other_vehicles_type`` names a vehicle class that highway-env imports. Before tap-bench calls
anything such a name points at:

1. the module's source is found on the import path **without importing it** (no module
   code runs); a name outside tap-bench and highway-env must be *defined* there as a class
   (a ``class`` statement, or a ``from ... import`` of one, followed), so ``os:system`` or
   ``subprocess:Popen`` is refused before any module is imported;
2. then the module is imported (its own top-level code runs: only run definitions you
   trust) and the object must be a class of the right kind: one implementing the
   :class:`~tap_bench.sim.policies.Policy` protocol (``reset`` and ``act`` methods), or a
   subclass of highway-env's ``Vehicle``. Only then is it called.

:func:`code_files` lists the source files an episode depends on through such a name: the
module, every module it imports transitively inside the user's own code (the folder on the
import path that holds it, unless that is site-packages or the standard library), and every
module of its top-level package. The episode cache hashes them (:mod:`tap_bench.bench.cache`).
A module loaded by name as the code runs (``importlib.import_module("helper")``) shows in no
import statement: :func:`recording` notes what a run imports while it builds and runs its
policies, scenarios and measures (and the files of modules run from their path, which no
import shows either), and :func:`loaded_user_code` gives those of the user's code
with their files' SHA-256, which the cache keeps with each entry (:func:`user_code_holds`).
"""

from __future__ import annotations

import ast
import contextlib
import functools
import hashlib
import importlib
import importlib.util
import sysconfig
import threading
from collections.abc import Iterator
from importlib.machinery import ModuleSpec, PathFinder
from pathlib import Path
from typing import Any

from tap_bench.errors import ParameterError

__all__ = ["MAX_CODE_FILES", "TRUSTED_PACKAGES", "check_class_name", "code_digest",
           "code_files", "find_module_source", "import_checked_class", "loaded_user_code",
           "recording", "user_code_holds"]

TRUSTED_PACKAGES = ("tap_bench", "highway_env")
"""Packages whose classes are imported without the static check (their code ships with the
install; a class of theirs must still be of the right kind)."""
MAX_CODE_FILES = 5000
"""The most source files :func:`code_files` follows for one name: a user package larger than
this is refused rather than hashed file by file on every run."""
_FOLLOW_DEPTH = 8  # re-exports followed from module to module when looking for a class


def find_module_source(module: str, memo: dict[str, ModuleSpec | None] | None = None
                       ) -> ModuleSpec | None:
    """The spec of ``module`` found on the import path without running any of its code (nor
    its parent packages'), or None when there is no such module.

    Args:
        module: the dotted name.
        memo: specs found so far by name, filled here: a caller looking up many names looks
            up each package once (the same answers while the files do not change).
    """
    parts = module.split(".")
    if not all(p.isidentifier() for p in parts):
        return None
    if memo is not None and module in memo:
        return memo[module]
    if len(parts) == 1:  # the top level through every finder (editable installs add theirs)
        try:
            spec = importlib.util.find_spec(module)
        except (ImportError, ValueError):
            spec = None
    else:  # ... and each submodule in its parent's folders
        parent = find_module_source(module.rpartition(".")[0], memo)
        locations = parent.submodule_search_locations if parent is not None else None
        spec = PathFinder.find_spec(module, list(locations)) if locations else None
    if memo is not None:
        memo[module] = spec
    return spec


def _source_path(spec: ModuleSpec | None) -> Path | None:
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        return None
    path = Path(spec.origin)
    return path if path.is_file() else None


def _parse(path: Path) -> ast.Module | None:
    try:
        return ast.parse(path.read_bytes(), filename=str(path))
    except (OSError, SyntaxError, ValueError, RecursionError):
        return None


def _module_statements(tree: ast.Module) -> list[ast.stmt]:
    """Top-level statements, those inside module-level ``if``/``try`` blocks included."""
    out: list[ast.stmt] = []
    todo = list(tree.body)
    while todo:
        node = todo.pop(0)
        out.append(node)
        if isinstance(node, ast.If):
            todo[:0] = [*node.body, *node.orelse]
        elif isinstance(node, ast.Try):
            todo[:0] = [*node.body, *[s for h in node.handlers for s in h.body],
                        *node.orelse, *node.finalbody]
    return out


def _absolute(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute module name of a ``from X import`` in ``module``."""
    if not node.level:
        return node.module or ""
    parts = module.split(".")
    base = parts if is_package else parts[:-1]
    base = base[:len(base) - (node.level - 1)] if node.level > 1 else base
    return ".".join([*base, *([node.module] if node.module else [])])


def _defines_class(module: str, name: str, depth: int = 0) -> bool:
    """Whether ``module``'s source defines ``name`` as a class, following ``from ... import``
    re-exports (read, never run)."""
    if depth > _FOLLOW_DEPTH:
        return False
    spec = find_module_source(module)
    path = _source_path(spec)
    tree = _parse(path) if path is not None else None
    if tree is None:
        return False
    is_package = path.name == "__init__.py"
    for node in _module_statements(tree):
        if isinstance(node, ast.ClassDef) and node.name == name:
            return True
        if isinstance(node, ast.ImportFrom):
            for alias in node.names:
                if (alias.asname or alias.name) == name and alias.name != "*":
                    source = _absolute(module, is_package, node)
                    if _defines_class(source, alias.name, depth + 1):
                        return True
    return False


def _split_name(text: str, parameter: str, separator: str) -> tuple[str, str]:
    if separator == ":":
        module, _, attribute = str(text).partition(":")
    else:
        module, _, attribute = str(text).rpartition(".")
    if (not module or not attribute or not attribute.isidentifier()
            or not all(p.isidentifier() for p in module.split("."))):
        shape = "'module:Class'" if separator == ":" else "'package.module.Class'"
        raise ParameterError(parameter, text, f"a class named as {shape}")
    return module, attribute


def check_class_name(text: str, parameter: str, *, separator: str = ":",
                     source: str = "") -> tuple[str, str]:
    """Check, without running any code, that ``text`` names a class defined in a module on
    the import path (rule 1 of the module docstring).

    Args:
        text: ``"module:Class"`` (``separator=":"``) or ``"package.module.Class"``
            (``separator="."``).
        parameter: the field, for the message (``factory``, ``other_vehicles_type``).
        source: the file that names it, for the message.

    Returns:
        (module, class name).

    Raises:
        ParameterError: naming the field, the value and what is wrong.
    """
    module, attribute = _split_name(text, parameter, separator)
    where = f"{source}: " if source else ""
    if find_module_source(module) is None:
        raise ParameterError(parameter, text, "an importable module", message=(
            f"{where}{parameter} {text!r}: no module {module!r} on the import path; is its "
            "folder on PYTHONPATH?"))
    if module.split(".")[0] in TRUSTED_PACKAGES:
        return module, attribute
    if not _defines_class(module, attribute):
        raise ParameterError(parameter, text, "a class", message=(
            f"{where}{parameter} {text!r}: {module!r} defines no class {attribute!r} (read "
            "without running it); a definition names a class, which tap-bench checks before "
            "calling it. Definition files are code: use only files you trust."))
    return module, attribute


def import_checked_class(text: str, parameter: str, *, kind: str, separator: str = ":",
                         base: type | None = None, methods: tuple[str, ...] = (),
                         source: str = "") -> type:
    """The class ``text`` names, after :func:`check_class_name`, imported and checked to be
    a subclass of ``base`` with callable ``methods`` (rule 2 of the module docstring).
    Nothing of it is called.

    Raises:
        ParameterError: naming the field, the value and what is wrong.
    """
    module, attribute = check_class_name(text, parameter, separator=separator, source=source)
    where = f"{source}: " if source else ""
    try:
        target = getattr(importlib.import_module(module), attribute)
    except (ImportError, AttributeError) as err:
        raise ParameterError(parameter, text, "an importable class", message=(
            f"{where}{parameter} {text!r} cannot be imported ({err}).")) from err
    missing = [m for m in methods if not callable(getattr(target, m, None))]
    if (not isinstance(target, type) or (base is not None and not issubclass(target, base))
            or missing):
        what = "not a class" if not isinstance(target, type) else (
            f"no method {', '.join(missing)}" if missing else f"not a subclass of "
            f"{base.__module__}.{base.__qualname__}")
        raise ParameterError(parameter, text, kind, message=(
            f"{where}{parameter} {text!r} is {what}; it must be {kind}. It was not called."))
    return target


@functools.cache
def _excluded_roots() -> tuple[Path, ...]:
    """Folders whose modules are not the user's code: the standard library, site-packages."""
    paths = sysconfig.get_paths()
    roots = {Path(paths[k]).resolve() for k in ("stdlib", "platstdlib", "purelib", "platlib")
             if k in paths}
    return tuple(roots)


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.relative_to(folder)
        return True
    except ValueError:
        return False


def _imports(module: str, path: Path, tree: ast.Module) -> set[str]:
    """Every module name an import statement of ``tree`` may load (functions included)."""
    is_package = path.name == "__init__.py"
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = _absolute(module, is_package, node)
            if base:
                out.add(base)
                out.update(f"{base}.{alias.name}" for alias in node.names if alias.name != "*")
    return out


def code_files(module: str) -> dict[str, Path]:
    """The source files an object of ``module`` depends on inside the user's code (module
    docstring), by module name; empty when ``module`` has no Python source.

    Raises:
        ParameterError: more than :data:`MAX_CODE_FILES` files.
    """
    spec = find_module_source(module)
    origin = _source_path(spec)
    if origin is None:
        return {}
    top = module.split(".")[0]
    top_spec = find_module_source(top)
    top_path = _source_path(top_spec)
    # the folder on the import path that holds the top level: the user's code
    if top_path is None:
        return {module: origin}
    root = (top_path.parent.parent if top_path.name == "__init__.py" else top_path.parent)
    root = root.resolve()
    excluded = _excluded_roots()
    followable = not any(_inside(root, e) for e in excluded)
    files: dict[str, Path] = {}
    if top_path.name == "__init__.py":  # every module of the top-level package
        package = top_path.parent
        for path in sorted(package.rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            rel = path.relative_to(package.parent).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            files[".".join(parts)] = path
            if len(files) > MAX_CODE_FILES:
                raise _too_many(module)
    todo, seen = [module], set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        path = _source_path(find_module_source(name)) if name != module else origin
        if path is None:
            continue
        resolved = path.resolve()
        first = name.split(".")[0]
        if ((first in TRUSTED_PACKAGES and top not in TRUSTED_PACKAGES)
                or not (_inside(resolved, root) and (followable or first == top))):
            continue  # tap-bench's and highway-env's code are keyed by their versions
        files[name] = path
        if len(files) > MAX_CODE_FILES:
            raise _too_many(module)
        tree = _parse(path)
        if tree is not None:
            todo.extend(_imports(name, path, tree) - seen)
    return dict(sorted(files.items()))


def _too_many(module: str) -> ParameterError:
    return ParameterError("code", module, f"at most {MAX_CODE_FILES} source files",
                          message=f"the code of {module!r} spans more than {MAX_CODE_FILES} "
                          "source files (tap_bench.usercode.MAX_CODE_FILES); episodes of it "
                          "cannot be keyed file by file. Move the policy into a smaller "
                          "package.")


def code_digest(module: str) -> dict[str, Any] | None:
    """``{"files": n, "sha256": ...}`` over the names and bytes of :func:`code_files`, or
    None when ``module`` has no Python source to hash."""
    files = code_files(module)
    if not files:
        return None
    digest = hashlib.sha256()
    for name, path in files.items():
        digest.update(name.encode() + b"\0")
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return {"files": len(files), "sha256": digest.hexdigest()}


_RECORDER: list[Any] = []  # this process's ImportRecorder, once installed
_THREAD = threading.local()  # .active: the runs this thread is building or running (a stack)
_RUNNING: dict[str, int] = {}  # run -> the threads building or running its code now
_RUNNING_LOCK = threading.Lock()
_NOTED: dict[str, dict[str, None]] = {}  # run -> modules first imported while it was active
_EXECUTED: dict[str, dict[str, None]] = {}  # run -> source files of code run while active


def _active_runs() -> list[str]:
    """The runs code running in this thread now belongs to: the innermost run this thread
    entered (:func:`recording`); in a thread that entered none (one a policy started, say)
    every run active in the process, as any of them may have started it (a module noted
    for a run it does not belong to only makes that run's cache entries stricter)."""
    stack = getattr(_THREAD, "active", None)
    if stack:
        return [stack[-1]]
    if not _RUNNING:
        return []
    with _RUNNING_LOCK:
        return list(_RUNNING)


def _note(name: str) -> None:
    for run in _active_runs():
        _NOTED.setdefault(run, {}).setdefault(name)


def _executed(event: str, args: tuple[Any, ...]) -> None:
    """Audit hook (``sys.addaudithook``): the source file of every code object ``exec``
    runs while a run is active, a module's body among them. A module run from its path
    (``spec_from_file_location`` and ``exec_module``) passes no finder and enters no
    ``sys.modules``: only this sees it."""
    if event == "exec" and (_RUNNING or getattr(_THREAD, "active", None)):
        filename = getattr(args[0], "co_filename", None)
        if isinstance(filename, str) and filename.endswith(".py"):
            for run in _active_runs():
                _EXECUTED.setdefault(run, {}).setdefault(filename)


@contextlib.contextmanager
def recording(run: str) -> Iterator[None]:
    """Within the block, note every module this process imports for the first time as the
    code of run ``run`` (:class:`tap_bench.importhooks.ImportRecorder`), and the source file
    of every module run from its path (an audit hook on ``exec``): a run builds its
    policies and scenarios and runs its episodes and measures inside it, so that
    :func:`loaded_user_code` knows what they loaded by name, which no import statement
    shows. A module imported earlier in the process (by another run) is not noted again.
    Runs in different threads at once are kept apart: what a thread loads is noted for the
    run it entered last (in a thread that entered none, for every run active then)."""
    import sys

    from tap_bench.importhooks import ImportRecorder

    if not _RECORDER:
        _RECORDER.append(ImportRecorder(_note))
        sys.addaudithook(_executed)  # for the life of the process: hooks cannot be removed
    _RECORDER[0].install()
    stack = _THREAD.__dict__.setdefault("active", [])
    stack.append(run)
    with _RUNNING_LOCK:
        _RUNNING[run] = _RUNNING.get(run, 0) + 1
    try:
        yield
    finally:
        stack.pop()
        with _RUNNING_LOCK:
            _RUNNING[run] -= 1
            if not _RUNNING[run]:
                del _RUNNING[run]


@functools.lru_cache(maxsize=8192)
def _is_user_file(name: str, path: Path) -> bool:
    if name.split(".")[0] in TRUSTED_PACKAGES:
        return False
    resolved = path.resolve()
    return not any(_inside(resolved, root) for root in _excluded_roots())


def loaded_user_code(run: str) -> dict[str, dict[str, str]]:
    """``{module: {"path": ..., "sha256": ...}}`` of every module of the user's code (a
    Python source outside tap-bench, highway-env, the standard library and site-packages)
    this process imported while it built or ran the code of run ``run``
    (:func:`recording`), and of every other run of this process: a module imported by an
    earlier or concurrent run is not imported again, so nothing shows whether run ``run``
    uses it too, and an entry that names a module it did not need only misses more often.
    What an episode or label entry made now may depend on beyond its key (a module loaded
    by name as the policy or a measure ran): the cache keeps it with the entry and serves
    the entry only while every file still hashes the same (:func:`user_code_holds`)."""
    import sys

    out: dict[str, dict[str, str]] = {}
    noted = {name: None for run_noted in list(_NOTED.values()) for name in list(run_noted)}
    executed = {f: None for run_executed in list(_EXECUTED.values())
                for f in list(run_executed)}
    for name in noted:
        path = _source_path(getattr(sys.modules.get(name), "__spec__", None))
        if path is None or not _is_user_file(name, path):
            continue
        try:
            out[name] = {"path": str(path), "sha256": hashlib.sha256(path.read_bytes())
                         .hexdigest()}
        except OSError:
            continue
    seen = {info["path"] for info in out.values()}
    for filename in executed:  # modules run from their path
        path = Path(filename)
        if filename in seen or not _run_from_user_file(filename):
            continue
        try:
            out[f"file:{filename}"] = {"path": filename, "sha256": hashlib.sha256(
                path.read_bytes()).hexdigest()}
        except OSError:
            continue
    return dict(sorted(out.items()))


@functools.lru_cache(maxsize=8192)
def _run_from_user_file(filename: str) -> bool:
    """Whether a source file that ``exec`` ran is the user's: a file outside tap-bench's
    trusted packages, the standard library and site-packages (decided once per file name;
    a run executes the same library files episode after episode)."""
    path = Path(filename)
    if not path.is_file() or not _is_user_file("", path):
        return False
    resolved = path.resolve()
    return not any(_inside(resolved, root) for root in _trusted_roots())


@functools.cache
def _trusted_roots() -> tuple[Path, ...]:
    """The folders of :data:`TRUSTED_PACKAGES` (found without importing them)."""
    roots = []
    for name in TRUSTED_PACKAGES:
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            continue
        for location in (spec.submodule_search_locations or []) if spec else []:
            roots.append(Path(location).resolve())
    return tuple(roots)


def user_code_holds(loaded: Any) -> bool:
    """Whether every file of ``loaded`` (:func:`loaded_user_code` of an entry) still exists
    and hashes the same.

    Raises:
        ValueError: ``loaded`` is not of that shape.
    """
    if not isinstance(loaded, dict):
        raise ValueError("the loaded modules are not an object")
    for name, info in loaded.items():
        if (not isinstance(info, dict) or not isinstance(info.get("path"), str)
                or not isinstance(info.get("sha256"), str)):
            raise ValueError(f"loaded module {str(name)[:80]!r} is malformed")
        try:
            data = Path(info["path"]).read_bytes()
        except (OSError, ValueError):
            return False
        if hashlib.sha256(data).hexdigest() != info["sha256"]:
            return False
    return True
