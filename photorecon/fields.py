"""The former name of ``photorecon.config_checks`` (the config fields' declared values and their one check): the
same module object, so ``from photorecon.fields import check_config`` and ``photorecon.fields._HINTS`` reach
the same code."""
import sys

from . import config_checks

sys.modules[__name__] = config_checks
