import signal

# Ctrl-C held back while the command line's modules load (numpy's C extension turns a KeyboardInterrupt during its
# import into an ImportError with a page of advice): it arrives once they are loaded, as one line and exit code 130
held = hasattr(signal, "pthread_sigmask")
before = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if held else None
try:
    try:
        from .cli import main
    finally:
        if held:
            signal.pthread_sigmask(signal.SIG_SETMASK, before)
except KeyboardInterrupt:
    import sys

    print("spotlights: interrupted", file=sys.stderr)
    exec("pass")  # noqa: S102 - clears CPython's unhandled-interrupt note (spotlights.cli._forget_interrupt)
    raise SystemExit(130) from None

raise SystemExit(main())
