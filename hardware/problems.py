"""Old import path of :mod:`jaxrecog.problems` (the problem-list formatter
moved to the core, a leaf module that the core, the CLI and this package use);
kept so that code written against ``jaxrecog.hardware.problems`` still works."""

from ..problems import *  # noqa: F401,F403
from ..problems import __all__  # noqa: F401
