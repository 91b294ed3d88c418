"""`naocal offsets export`: an offsets file in the formats of the software that uses it.

One module per target: bhuman, hulks, naodevils (team configs, fresh or merged into the team's files), urdf (a
calibrated robot model, and the offsets JSON itself). cfgtext and jsontext edit single values in a team's text so
that merges keep every other byte; common holds what they share. Formats, values and signs: docs/EXPORTS.md.
"""

TEAM_FORMATS = ("bhuman", "hulks", "naodevils")
FORMATS = TEAM_FORMATS + ("urdf", "json")
