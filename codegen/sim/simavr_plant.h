/* printer-codegen simavr harness: thermal plants for the heater runtime (simavr_plant.c). */
#ifndef SIMAVR_PLANT_H
#define SIMAVR_PLANT_H

#include <sim_avr.h>

/* Read the plant file named by the harness option plant=FILE and hook the plants into `avr`; 0 on success. */
int plant_setup(avr_t *avr, const char *path);

/* After each instruction: integrate the plants up to the current cycle, inject faults, log samples. */
void plant_follow(avr_t *avr);

/* At the end of a run: the final figures into the plant's log, and close it. */
void plant_finish(avr_t *avr);

#endif /* SIMAVR_PLANT_H */
