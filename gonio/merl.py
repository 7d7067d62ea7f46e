"""The MERL binary BRDF format under its first public name: see :mod:`gonio.io.merl`.

``gonio.merl.read_merl`` (and the other names) keep working for code written before the file
formats moved to :mod:`gonio.io`.
"""

from gonio.io.merl import *  # noqa: F403
from gonio.io.merl import __all__  # noqa: F401
