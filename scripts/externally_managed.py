"""Print "yes" when this Python refuses `pip install` into itself (PEP 668), else "no".

A Python is externally managed when its standard-library folder holds an ``EXTERNALLY-MANAGED``
file (Debian 12, Ubuntu 23.04 and later put one there) and it is not running inside a virtual
environment (a venv's Python is never externally managed, whatever its base). The Makefile asks
this to decide whether `make demo` / `make test` create and use a project `.venv`.
"""

import os
import sys
import sysconfig


def externally_managed() -> bool:
    """PEP 668's test: a marker file in the stdlib folder of an interpreter outside any virtual environment."""
    if sys.prefix != sys.base_prefix:
        return False
    return os.path.isfile(os.path.join(sysconfig.get_path("stdlib"), "EXTERNALLY-MANAGED"))


if __name__ == "__main__":
    print("yes" if externally_managed() else "no")
