"""``valvectl identify``: characterize a valve over Zenoh, fit it, and hand back a run configuration.

Modules, one concept each:

- :mod:`.protocol`: the excitation (range finding, the paper's growing sweep,
  reversals, steps), computed from the time available;
- :mod:`.session`: the open-loop session with its safety rules (duty limits,
  stale measurements, flow limit, signals), recording as it goes;
- :mod:`.link`: the Zenoh side of a session (keys, the second-commander check);
- :mod:`.timeline`: the recording on the even grid the valve lived (the duty held through
  missed periods), and what a busy machine cost it;
- :mod:`.analysis`: from the session's recording to the identified valve (timeline,
  lag and delay, models), a recording too damaged refused;
- :mod:`.dynamics`: lag and delay from the step tests, with their uncertainty;
- :mod:`.estimate`: every model kind fitted on the sweep, validated on the steps;
- :mod:`.tune`: the plant built from the identification, a short gain sweep,
  the run configuration;
- :mod:`.report`: ``report.md`` and its figures.
"""
