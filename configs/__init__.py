"""The shipped configs. Installed as the package `pure_hil_configs`, so a wheel finds them from any folder
(drivers/resources.py); in a source checkout they are read from here."""
