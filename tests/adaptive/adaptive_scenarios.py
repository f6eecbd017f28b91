"""Small scenarios shared by the adaptive tests."""

POINT_SCENARIO = """
cellplan: 1
name: tiny
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 10, ymax: 10}
  obstacles:
    A: {type: box, min: [4.0, 0.0], max: [6.0, 7.0]}
robot: {type: point, start: [1.0, 1.0]}
adaptive:
  resolution: 0.1
  attach_radius: 1.0
  goals:
    home: {at: [1.0, 1.0]}
    g1: {at: [9.0, 1.0]}
    g2: {at: [6.5, 3.0], object: A}
  tasks: [g1, home, g1, g2, home, g1, home]
  changes:
    - after_task: 4
      type: add_object
      object: C
      shape: {type: box, min: [3.0, 7.5], max: [7.0, 8.5]}
"""
