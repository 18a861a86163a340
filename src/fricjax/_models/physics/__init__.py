"""Physics-based (grey-box) friction models: Stribeck curves, static laws, Dahl, LuGre, GMS, Maxwell-slip."""
