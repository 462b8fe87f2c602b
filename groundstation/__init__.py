"""The ground station: MAVLink link, vehicle state, web app, 3D view, recording and replay."""
