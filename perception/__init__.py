"""perception: RGB-D observations -> posteriors over each gear's planar pose (x, y, yaw).

Start at `perception.search.estimate_pose(obs, gear, Prior(x, y))`; observations come from
`perception.station_views.observe(station, root_context, camera)`. See docs/perception.md.
"""
