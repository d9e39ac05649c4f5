"""Imported by the fork server of the worker pools (:func:`spotlights.processes.process_pool_context`
preloads it): the fork server ends when the process that started it dies (Linux), and so do the
workers it forked (each asks for the same in its initializer). A SIGKILLed build leaves no
process behind.

It also ignores Ctrl-C: the fork server hands each process it forks the SIGINT handler it had
after its preloads, so every worker ignores Ctrl-C from its first instant (its initializer, e.g.
:func:`spotlights.processes._quiet_worker`, ignores it too, but only once its module is imported: a
Ctrl-C in between printed the worker's own traceback beside the run's one line). Ctrl-C is the
parent's, which stops its workers."""

import signal

from .processes import die_with_parent

signal.signal(signal.SIGINT, signal.SIG_IGN)
die_with_parent()
