"""Engine environments: an engine version beside another (``--engine mujoco==3.1.6``).

An engine named with a version, or registered with an ``environment`` of its own, runs in worker
processes of an isolated Python environment that freebody builds on first use and caches.  The
modules, by job:

- :mod:`.requirements`: engine requirements parsed, checked and normalised.
- :mod:`.cache`: where environments live and under which name, their markers and locks, listing
  and clearing them (``freebody envs list`` / ``clear``).
- :mod:`.build`: building an environment (venv, pip or uv, a copy of freebody's source) or reusing
  the cached one (``freebody envs create``; on first use by ``freebody run``).
- :mod:`.describe`: what an engine offers there, asked with the environment's interpreter.
- :mod:`.engines`: for one invocation, which engines run isolated, their environments and
  descriptions, and the interpreter of each engine's workers.
- :mod:`.versions`: the runs of two or more versions of one engine read side by side (the
  reports' "Engine versions" section, ``freebody compare --against``).

Nothing here is imported by ``import freebody``; each module is imported where it is used.
"""
