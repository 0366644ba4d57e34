"""The CAN side of the bench: an ODrive CANSimple (firmware 0.6) drive profile.

- :mod:`protocol.can.codec`: frames <-> typed messages through the DBC (cantools), strict.
- :mod:`protocol.can.dbc`: the CANSimple 0.6 message set as data; renders the DBC.
- :mod:`protocol.can.drive_profile`: the host's drive lifecycle as a pure state machine (the
  virtual drives are the plant emulator's: :mod:`plant_emulator.odrive`).
- :mod:`protocol.can.wheel_mapping`: (tau1, tau2) of the paper's model (1) <-> motor torques.
- :mod:`protocol.can.bus_load`: bit length of classical CAN frames and bus load.
- :mod:`protocol.can.bus_factory`: a python-can Bus from the scenario's ``[can]`` table.
- :mod:`protocol.can.zenoh_bus`: the default bus, CAN frames over Zenoh on loopback.
"""
