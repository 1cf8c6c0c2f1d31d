"""The mash program: a file of steps (`model`), a pure runner that turns it into the setpoint
(`runner`), its progress kept across restarts (`store`), the daemon's side (`driver`), and a
BeerXML recipe's mash steps read as a program (`beerxml`)."""
