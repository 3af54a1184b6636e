"""What the three nodes decide, without ROS: one place for the nodes' logic.

- :mod:`.driver`: the driver node's :class:`~pmdc_ident.node_logic.driver.Driver`
  (commands, the safety monitor, the watchdog, limits at run time, the ordered stop);
- :mod:`.session`: the identification node's session (the state machine, the
  controller that records, checks the link and hands the record to the worker,
  ``plan: auto``);
- :mod:`.drift_monitor`: the monitor node's
  :class:`~pmdc_ident.node_logic.drift_monitor.DriftMonitor` (also behind
  ``pmdc-ident monitor`` on a bag).

Each node in :mod:`pmdc_ident.nodes` turns its callbacks into calls of these classes
and publishes what they return; the tests drive them without DDS. This layer sits
above the backends (the driver owns one) and below the command line and the nodes'
processes; it imports nothing from either.
"""
