/* The rigs a bridge can serve (layouts.h). Add an entry for a rig file of your own. */
#include "layouts.h"

#include <string.h>

const struct bridge_layout bridge_layouts[] = {
    /* hal/sim_3joint.toml, the lab's cylinder rig with all three joints: inputs ai0-ai2 (the
     * RDC506 potentiometers), ai6 (their 5 V supply, for the ratio), ai7 (the AS-FS amplifier);
     * outputs ao0-ao5 (the six ITV0051 regulators, head and rod side per joint). */
    {"cylinder-3", 5, 6, {0, 0, 0, 0, 0, 0}},
    /* hal/sim_2joint.toml, the built-in rig: bottom and middle joints only. */
    {"cylinder-2", 4, 4, {0, 0, 0, 0}},
};

const unsigned bridge_layout_count = sizeof bridge_layouts / sizeof bridge_layouts[0];

const struct bridge_layout *bridge_layout_find(const char *name)
{
    for (unsigned i = 0; i < bridge_layout_count; i++)
        if (strcmp(bridge_layouts[i].name, name) == 0)
            return &bridge_layouts[i];
    return 0;
}
