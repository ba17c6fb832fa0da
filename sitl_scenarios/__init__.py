"""The scenarios fuseplan ships: ``*.toml`` scenario files and the ``*.asc`` terrain the hard maps name beside them.

Package data, so a wheel install carries them; code finds them with :func:`planner.distribution.shipped_scenarios`
(``fuseplan demo`` flies ``rescue_dynamic.toml``, the benches plan on the others). Nothing to import here.
"""
