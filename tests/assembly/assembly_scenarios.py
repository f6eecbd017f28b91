"""Scenario texts the assembly tests share."""

# Seven unit discs whose paper-rule T map at k=48 jams (two discs hand the turn back and
# forth; the same problem as PING_PONG in test_sequential.py), written as a scenario file.
JAM = """cellplan: 1
name: jam
workcell:
  bounds: {xmin: -12, ymin: -12, xmax: 12, ymax: 12}
discs:
  boundary: {type: disc, center: [0, 0], radius: 11.832159566199232}
  k: 48
  discs:
    - {radius: 1, start: [-1.5869574702043012, -7.548733073037667], goal: [0.0, 0.0]}
    - {radius: 1, start: [-8.750518505339972, 3.293009396759315],
       goal: [-1.0036711316621478, -1.738409394128992]}
    - {radius: 1, start: [5.781808107370352, 3.8062636853552334],
       goal: [1.0036711316621478, -1.738409394128992]}
    - {radius: 1, start: [-3.2764170041026963, 3.236272247279302],
       goal: [2.0073422633242957, 0.0]}
    - {radius: 1, start: [-0.817040215745796, 8.891677773140197],
       goal: [1.0036711316621478, 1.738409394128992]}
    - {radius: 1, start: [-4.5921874139775145, 0.22416827260256159],
       goal: [-1.0036711316621478, 1.738409394128992]}
    - {radius: 1, start: [-7.527354726059178, -3.9485190004263058],
       goal: [-2.0073422633242957, 0.0]}
"""
