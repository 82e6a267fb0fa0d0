/*
 * avatar.h: the default avatar, one definition for movement
 * (scene/move.c), refinement (refine/refine.c: the space users need) and the
 * client: a box 0.6 m wide and deep, 1.8 m tall, that climbs steps up to
 * 0.35 m (a stair riser is about 0.18 m; a kerb or low platform fits).
 */
#ifndef CVRE_AVATAR_H
#define CVRE_AVATAR_H

#define AVATAR_WIDTH 0.6f
#define AVATAR_HEIGHT 1.8f
#define AVATAR_STEP 0.35f

#endif
