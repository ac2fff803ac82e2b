"""Suite-wide test settings.

Hypothesis runs derandomized under CI (``CI`` set in the environment), so a CI result can be reproduced
exactly; a developer's run explores new examples each time and keeps failures in ``.hypothesis/``.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci", derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow], print_blob=True
)
settings.register_profile("dev", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if os.environ.get("CI") else "dev")
