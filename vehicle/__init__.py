"""The onboard side: scenes, simulated vehicle and sensors, memory map, planning, missions, MAVLink."""

__version__ = "0.1.0"
