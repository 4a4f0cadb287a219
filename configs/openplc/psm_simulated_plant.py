# OpenPLC v3 Python SubModule (PSM) script for atc-plc demos: raises %IX49.7 SimulatedPlant, so the program's
# plant models (FB_CarouselPlant, FB_ChangerPlant) stand in for the machine on a stock OpenPLC runtime.
#
# Use: in OpenPLC's web UI, Hardware -> Hardware Layer "Python on Linux (PSM)", paste this file as the PSM
# code, save, then start the PLC. The PSM layer transfers %IX0.0..%IX49.7 only, which is why SimulatedPlant
# lives at %IX49.7 in modbus_map/map.toml. Never use it on a machine with real I/O: the program would ignore
# the real sensors (E-stop included) and drive the outputs from its models.
import time

import psm

SIMULATED_PLANT = "IX49.7"   # modbus_map/map.toml: SimulatedPlant, discrete input 399


def hardware_init():
    psm.start()


def update_inputs():
    psm.set_var(SIMULATED_PLANT, True)


def update_outputs():
    pass


if __name__ == "__main__":
    hardware_init()
    while not psm.should_quit():
        update_inputs()
        update_outputs()
        time.sleep(0.1)
    psm.stop()
