"""The ``spotlights`` command's entry point: the console script (``[project.scripts]``) and ``python -m spotlights``.

A Ctrl-C must end a command with one line and exit code 130, never a traceback or an abort. Two kinds of import
cannot take a KeyboardInterrupt in their middle:

* numpy's C extension turns one into an ImportError with a page of advice; pybind11 modules may abort the
  process (``terminate called after throwing an instance of 'pybind11::error_already_set'``): held back while
  the command line's modules load, by blocking SIGINT in this thread (:func:`main`);
* the heavy C++ packages a command imports later, while it runs (torch, when the model loads): by then other
  threads exist (a track worker's queue feeder, BLAS threads), any of which may take the signal, so blocking it
  in this thread is not enough. :func:`guard_imports` defers the interrupt instead: a Ctrl-C that comes while
  such a package's first import runs is noted, and raised as a KeyboardInterrupt once that import is complete.

The package's import holds Ctrl-C first thing when it starts the command (``spotlights._hold_sigint_for_the_command``),
so the package's, numpy's and this module's imports are covered too; :func:`main` delivers the held signal once the
command line is loaded. Python's own start-up before the package's first line (a few tens of milliseconds) is not.
"""

from __future__ import annotations

import importlib.abc
import signal
import sys
import threading
from collections.abc import Iterable

#: top-level packages whose first imports cannot take a KeyboardInterrupt in their middle, which take a Ctrl-C only
#: once complete: C++ (pybind11) module initialisers (a KeyboardInterrupt raised in Python code they call back aborts
#: the process), and packages that catch BaseException around their optional imports (trimesh keeps the interrupt
#: as a placeholder module: the Ctrl-C was lost, or came back later as a TypeError traceback about an
#: ``ExceptionWrapper``; ``dataset build`` of a mesh folder, 1.2-1.6 s in)
DEFERRED_IMPORTS = frozenset({"torch", "onnxruntime", "open3d", "scipy", "trimesh", "embreex", "h5py", "matplotlib"})


class _Deferral:
    """The state of :func:`guard_imports`: how deep in a guarded import this process is, and a Ctrl-C noted there."""

    def __init__(self) -> None:
        self.depth = 0
        self.pending = False
        self.previous = None  # the SIGINT handler before guard_imports

    def on_sigint(self, signum, frame) -> None:
        if self.depth > 0:
            self.pending = True  # raised when the guarded import is complete
            return
        handler = self.previous
        if handler == signal.SIG_IGN:
            return
        if callable(handler) and handler != self.on_sigint:  # bound methods: equal, never the same object
            handler(signum, frame)
            return
        raise KeyboardInterrupt  # the default handler's (and SIG_DFL's, as Python starts)

    def enter(self) -> None:
        self.depth += 1

    def leave(self) -> None:
        self.depth -= 1
        if self.depth == 0 and self.pending:
            self.pending = False
            raise KeyboardInterrupt


_STATE = _Deferral()


class _GuardedLoader:
    """A module loader that runs the wrapped ``loader``'s module creation and execution as one guarded import, and
    puts the wrapped loader back on the module (its ``__loader__`` and ``__spec__.loader``) when done."""

    def __init__(self, loader) -> None:
        self._loader = loader

    def create_module(self, spec):
        _STATE.enter()
        try:
            return self._loader.create_module(spec)
        finally:
            _STATE.leave()

    def exec_module(self, module) -> None:
        _STATE.enter()
        try:
            self._loader.exec_module(module)
        finally:
            try:  # a module may replace its own class and refuse new attributes (torch.distributed.config)
                if module.__dict__.get("__loader__") is self:
                    module.__dict__["__loader__"] = self._loader
                if getattr(module, "__spec__", None) is not None and module.__spec__.loader is self:
                    module.__spec__.loader = self._loader
            except (AttributeError, TypeError):
                pass
            _STATE.leave()

    def __getattr__(self, name: str):
        return getattr(self._loader, name)


class _GuardFinder(importlib.abc.MetaPathFinder):
    """Finds first imports of :data:`DEFERRED_IMPORTS` (any of their modules) with the other finders and guards
    their loading (:class:`_GuardedLoader`)."""

    def __init__(self, packages: Iterable[str]) -> None:
        self.packages = frozenset(packages)

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] not in self.packages or name in sys.modules:
            return None
        for finder in sys.meta_path:
            find = getattr(finder, "find_spec", None)
            if finder is self or isinstance(finder, _GuardFinder) or find is None:
                continue
            spec = find(name, path, target)
            if spec is not None:
                break
        else:
            return None
        if spec.loader is not None and hasattr(spec.loader, "exec_module"):
            spec.loader = _GuardedLoader(spec.loader)
        return spec


def guard_imports(packages: Iterable[str] = DEFERRED_IMPORTS) -> None:
    """From now on, a Ctrl-C (SIGINT) that comes while the first import of a module of ``packages`` (top-level
    names) runs is raised as a KeyboardInterrupt once that import is complete, not in its middle. Installs a SIGINT
    handler that defers to the one before it outside such imports, and an import finder; main thread only (Python
    runs signal handlers there); calling it again adds ``packages``."""
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("guard_imports: signal handlers can be set in the main thread only")
    if signal.getsignal(signal.SIGINT) != _STATE.on_sigint:
        _STATE.previous = signal.getsignal(signal.SIGINT)
        signal.signal(signal.SIGINT, _STATE.on_sigint)
    sys.meta_path.insert(0, _GuardFinder(packages))


def main() -> int:
    """Run the command line on ``sys.argv``; returns its exit code (130 for a Ctrl-C while it loads)."""
    held = hasattr(signal, "pthread_sigmask")
    before = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if held else None
    package = sys.modules.get("spotlights")
    early = package.__dict__.pop("_SIGINT_MASK_BEFORE", None) if package is not None else None
    if early is not None:  # the package's import already held Ctrl-C: the mask to restore is the one before it
        before = early
    try:
        try:
            guard_imports()
            from .cli import main as run
        finally:
            if held:
                signal.pthread_sigmask(signal.SIG_SETMASK, before)  # a Ctrl-C held meanwhile is raised here
    except KeyboardInterrupt:
        print("spotlights: interrupted", file=sys.stderr)
        exec("pass")  # noqa: S102 - clears CPython's unhandled-interrupt note (spotlights.processes.forget_interrupt)
        return 130
    code = run()
    if code in (130, 143):
        exit_within(EXIT_GRACE_S, code)
    return code


#: Seconds an interrupted command (Ctrl-C: 130, SIGTERM: 143) may spend in the interpreter's exit, after its one
#: line and its own clean-up, before the process ends regardless (:func:`exit_within`).
EXIT_GRACE_S = 20.0


def exit_within(seconds: float, code: int) -> None:
    """End the process with ``code`` (``os._exit``, standard streams flushed) if the interpreter's exit has not ended
    it within ``seconds``: a daemon thread's timer. The interpreter's exit joins what the command left running
    (``concurrent.futures`` joins its executors' manager threads), and an interrupt that came while a pool was
    being stopped could leave one waiting for ever: the command had printed its line and then never ended (4 of
    15 interrupted builds). Everything of the command's own (temporaries, parts, pools) is handled before its exit
    code is returned, so only the interpreter's waiting is cut short."""
    import os

    def hard_exit() -> None:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:  # noqa: BLE001 - a closed stream: nothing left to flush
                pass
        os._exit(code)

    timer = threading.Timer(seconds, hard_exit)
    timer.daemon = True
    timer.start()
