"""What both services run on, below them and above :mod:`protocol`: the absolute-deadline clock
and scheduling set-up (:mod:`runtime.realtime`), signals as a stop flag (:mod:`runtime.signals`),
the run's Zenoh sessions and credentials (:mod:`runtime.zsession`, :mod:`runtime.credentials`),
the start handshake (:mod:`runtime.startgate`) and the math namespace the laws and the plant
are written on (:mod:`runtime.mathns`)."""
