try:
    from .cli import main
except KeyboardInterrupt:  # Ctrl-C while the command line's modules load: one line and 130, as main() gives
    import sys

    print("spotlights: interrupted", file=sys.stderr)
    exec("pass")  # noqa: S102 - clears CPython's unhandled-interrupt note (spotlights.cli._forget_interrupt)
    raise SystemExit(130) from None

raise SystemExit(main())
