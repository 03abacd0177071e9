"""bogiemon: condition monitoring of Y25 freight-wagon primary suspensions from bogie-frame accelerometers.

The layers are the subpackages (tests/house.py checks them): drivers and detection at the bottom,
judgement and the simulator above them, the daemon, the back office (fleet) and the lab, and the
command line (cli) on top. Importing this package imports nothing else.
"""

__version__ = "0.4.0"
