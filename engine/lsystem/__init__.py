"""L-systems: grammars and their derivation (`grammar`), the turtle that turns a module
string into geometry (`turtle`), and the shipped grammar presets (`presets`).
Imports only engine.core."""
