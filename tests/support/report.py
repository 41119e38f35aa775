"""A table printed by the tests that measure (pytest -s shows it)."""


def report(title, header, rows):
    """Print a table (pytest -s shows it)."""
    print(f"\n{title}\n  " + "  ".join(f"{h:>11}" for h in header))
    for row in rows:
        print("  " + "  ".join(f"{v:>11.3g}" if isinstance(v, float) else f"{v!s:>11}" for v in row))
