"""``python -m bderiv``: the same as the ``bderiv`` command."""

if __name__ == "__main__":
    from .cli import main

    raise SystemExit(main())
