"""Identification exercises built from the library: the `compare` recipes, EMPS IDM and open-loop protocols."""
