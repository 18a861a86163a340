"""Systems built around friction models: the EMPS plant with its position controller."""
