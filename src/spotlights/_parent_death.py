"""Imported by the fork server of the worker pools (:func:`spotlights.utils.process_pool_context`
preloads it): the fork server ends when the process that started it dies (Linux), and so do the
workers it forked (each asks for the same in its initializer). A SIGKILLed build leaves no
process behind."""

from .utils import die_with_parent

die_with_parent()
