"""The lab: recipes, declared experiments and their helpers (not part of the installed package).

Importing this package registers the policy-side entries that research policies
use (the coverage memory, the residual on the info_gain planner), so that
``agents.load_agent`` can run such a policy.
"""

from research import coverage_memory, residual  # noqa: F401  (register their policy entries)
