"""The paper's figure and the report of a run.

* `figure_data`: `FigureData`, the arrays of one row of the figure, simulated and evaluated.
* `plot`: drawing rows of five panels (a–e) with matplotlib, and writing the PNG.
* `report`: `figure` (figure.png), `report` (everything about a run), the extra-damping ρ.
"""
