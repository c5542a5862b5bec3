"""Old import path of :mod:`jaxrecog.dbformat` (the image-database format
moved to the core, a leaf module that the loader, the renderer and the
dataset rig use); kept so that code written against
``jaxrecog.hardware.dbformat`` still works."""

from ..dbformat import *  # noqa: F401,F403
from ..dbformat import __all__  # noqa: F401
