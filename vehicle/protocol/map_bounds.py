"""What a vehicle's memory map may be: the settings allow no more, and a station's map receiver believes no more.

Apart from ``mapstream`` (which checks streams against these) so that the
settings, which every command line's help shows, need no numpy to know them.
"""

MAX_SIDE = 4000  # cells a side: 16 M cells (16 MB of int8 on each end), twice the default map's 2000
MAX_SPACE = 1000.0  # m: the widest half-width of a vehicle's space (its settings' space_size)
MIN_RESOLUTION, MAX_RESOLUTION = 0.01, 50.0  # cells/m of a vehicle's map (its settings' resolution)
MAX_REACH = 2 * MAX_SPACE + 1 / MIN_RESOLUTION  # m: the widest map a vehicle makes (its side rounds up a cell)
