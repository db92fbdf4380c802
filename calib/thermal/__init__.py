"""How temperatures move: the lag of a sensing element behind its thermometer, a chamber's air and a DUT
behind it."""
