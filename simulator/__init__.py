"""Physics of the instruments.

Optics, sensors, the LBL imaging and Cornell three-axis gonioreflectometers, and the
simulated bench the fake devices read and change.
"""
