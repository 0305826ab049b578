/* The text of an authored video (docs/rendering.md "Authored videos"): a caption over a frame's
 * lower part and a title card filling a frame. Lines are broken at spaces to fit the width. */
#ifndef NS_RENDER_CARD_H
#define NS_RENDER_CARD_H

#include "image.h"
#include "text.h"

/* Draws text centred near the bottom of im, in up to three lines on a dark translucent band. */
void ns_card_caption(NsImage *im, NsFont *font, const char *text);

/* Fills im with a title card: title (big) and text (below it, up to eight lines), centred. */
void ns_card_title(NsImage *im, NsFont *big, NsFont *font, const char *title, const char *text);

#endif
