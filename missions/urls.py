from django.urls import path

from missions import views

urlpatterns = [
    path("", views.home, name="home"),
    path("vvs/rows/", views.vv_rows, name="vv-rows"),
    path("vvs/new/", views.vv_new, name="vv-new"),
    path("vvs/check/", views.vv_check, name="vv-check"),
    path("vvs/<uuid:vv_id>/", views.vv_detail, name="vv-detail"),
    path("vvs/<uuid:vv_id>/edit/", views.vv_edit, name="vv-edit"),
    path("vvs/<uuid:vv_id>/cancel/", views.vv_cancel, name="vv-cancel"),
    path("vvs/<uuid:vv_id>/restart/", views.vv_restart, name="vv-restart"),
    path("vvs/<uuid:vv_id>/storage.json", views.vv_storage_json, name="vv-storage-json"),
    path("vvs/<uuid:vv_id>/map.json", views.vv_map_history, name="vv-map-history"),
    path("map/", views.live_map, name="map"),
]
